//! The scene's bands: explicit (`bands`), evenly spaced (`band_range`), or the MS600Pro default.
//!
//! MS600Pro centres are from the paper (Table 2: 450, 555, 660, 720, 750, 840 nm). No public Yusense sheet
//! gives the widths, so the FWHMs are the project's choice, typical of this class of rig (MicaSense RedEdge:
//! 32/27/14/12/57 nm; DJI P4M: 32/32/32/32/52): 35, 27, 22, 10, 10, 30 nm. They only matter through the band
//! integration of the material spectra.

use super::scene::SceneDesc;
use super::spectra::Response;

/// One simulated band.
#[derive(Debug, Clone, PartialEq)]
pub struct SimBand {
    pub name: String,
    pub center_nm: f64,
    pub fwhm_nm: f64,
    pub response: Response,
}

/// The MS600Pro's six bands: (name, centre nm, FWHM nm).
pub const MS600PRO_BANDS: [(&str, f64, f64); 6] = [
    ("blue", 450.0, 35.0),
    ("green", 555.0, 27.0),
    ("red", 660.0, 22.0),
    ("rededge1", 720.0, 10.0),
    ("rededge2", 750.0, 10.0),
    ("nir", 840.0, 30.0),
];

/// The bands a scene asks for.
pub fn resolve_bands(desc: &SceneDesc) -> Vec<SimBand> {
    if let Some(list) = &desc.bands {
        return list
            .iter()
            .map(|b| {
                let response = match (&b.response, b.fwhm_nm) {
                    (Some(t), _) => Response::Table(t.iter().map(|k| (k[0], k[1])).collect()),
                    (None, w) => Response::Gaussian { center_nm: b.center_nm, fwhm_nm: w.unwrap_or(10.0) },
                };
                let fwhm_nm = b.fwhm_nm.unwrap_or_else(|| response.fwhm_nm());
                SimBand { name: b.name.clone(), center_nm: b.center_nm, fwhm_nm, response }
            })
            .collect();
    }
    if let Some(r) = &desc.band_range {
        let step = if r.count > 1 { (r.end_nm - r.start_nm) / (r.count - 1) as f64 } else { 0.0 };
        return (0..r.count)
            .map(|i| {
                let c = r.start_nm + step * i as f64;
                SimBand {
                    name: format!("b{i:03}"),
                    center_nm: c,
                    fwhm_nm: r.fwhm_nm,
                    response: Response::Gaussian { center_nm: c, fwhm_nm: r.fwhm_nm },
                }
            })
            .collect();
    }
    MS600PRO_BANDS
        .iter()
        .map(|&(n, c, w)| SimBand {
            name: n.to_string(),
            center_nm: c,
            fwhm_nm: w,
            response: Response::Gaussian { center_nm: c, fwhm_nm: w },
        })
        .collect()
}
