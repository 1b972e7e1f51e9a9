//! Irradiance per band, the denominator of reflectance `rho = pi * L / E`:
//! - from calibration-panel captures: the panel found in each band (or given as corners), saturated pixels
//!   counted and excluded, `E = pi * mean(L_panel) / rho_panel`, averaged over the panel captures;
//! - from the downwelling light sensor, per capture: DLS2 (`DLS:`/`Camera:` horizontal, direct and scattered
//!   irradiance with MicaSense's scale and firmware rules), DLS1 (sun-angle corrected), or DJI's `Irradiance`.
//!
//! The panel report ([`PanelReport`]) keeps, per panel capture and band, the region, its radiance, the
//! irradiance and the reflectance the panel gets back once calibrated (the check a user reads first).

use super::capture::Capture;
use super::error::RigError;
use super::meta::read_pixels;
use super::panel::{
    detect_panel, irradiance_from_panel, order_corners, region_stats, scale_quad, Quad, RegionStats, PANEL_INNER,
};
use super::radiometry::{saturation_level, to_radiance};

/// One band of one panel capture.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PanelBand {
    pub band: String,
    pub file: String,
    pub corners: Quad,
    /// How the corners were obtained: "detected" or "given".
    pub corners_source: String,
    pub radiance: RegionStats,
    pub panel_reflectance: f64,
    pub irradiance: f64,
    /// Mean reflectance of the panel region after calibration with the irradiance finally used.
    pub reflectance_back: f64,
}

/// What the panel captures gave.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PanelReport {
    pub captures: Vec<Vec<PanelBand>>,
    /// Irradiance per band (wavelength order), the mean over panel captures.
    pub irradiance: Vec<f64>,
}

/// Measures the panel in every band of every panel capture. `reflectance` is per band (wavelength order).
pub fn calibrate_panels(
    panels: &[Capture],
    reflectance: &[f64],
    corners: Option<Quad>,
    warnings: &mut Vec<String>,
) -> Result<PanelReport, RigError> {
    let nb = reflectance.len();
    let mut captures = Vec::new();
    let mut sums = vec![0.0; nb];
    for cap in panels {
        if cap.bands.len() != nb {
            return Err(RigError::Capture {
                capture: cap.key.clone(),
                reason: format!("panel capture has {} bands, the flight {nb}", cap.bands.len()),
            });
        }
        let mut rows = Vec::new();
        for (bi, b) in cap.bands.iter().enumerate() {
            let raw = read_pixels(&b.meta)?;
            let (rad, _) = to_radiance(b, &raw);
            let sat = saturation_level(b);
            let (quad, source) = match corners {
                Some(q) => (order_corners(q), "given"),
                None => {
                    let saturated: Vec<bool> = raw.iter().map(|v| *v >= sat).collect();
                    (detect_panel(&rad, &saturated, &b.meta.path)?, "detected")
                }
            };
            let inner = if source == "detected" { scale_quad(&quad, PANEL_INNER) } else { quad };
            let w = b.meta.width as usize;
            let stats = region_stats(&rad, &inner, |x, y| raw[y * w + x] >= sat);
            if stats.count < 25 {
                return Err(RigError::Panel {
                    path: b.meta.path.clone(),
                    reason: format!("only {} usable panel pixels ({} saturated)", stats.count, stats.saturated),
                });
            }
            if stats.saturated > 0 {
                warnings.push(format!(
                    "{}: {} saturated panel pixels excluded (lower the exposure for panel captures)",
                    b.meta.path.display(),
                    stats.saturated
                ));
            }
            let e = irradiance_from_panel(stats.mean, reflectance[bi]);
            sums[bi] += e;
            rows.push(PanelBand {
                band: b.band_name.clone(),
                file: b.meta.path.display().to_string(),
                corners: quad,
                corners_source: source.into(),
                radiance: stats,
                panel_reflectance: reflectance[bi],
                irradiance: e,
                reflectance_back: 0.0,
            });
        }
        captures.push(rows);
    }
    let irradiance: Vec<f64> = sums.iter().map(|s| s / panels.len().max(1) as f64).collect();
    for rows in &mut captures {
        for (bi, r) in rows.iter_mut().enumerate() {
            r.reflectance_back = std::f64::consts::PI * r.radiance.mean / irradiance[bi];
        }
    }
    Ok(PanelReport { captures, irradiance })
}

/// DLS irradiance per band of one capture (W/(m^2 nm) for MicaSense; DJI's own units): DJI's `Irradiance`, the DLS2
/// horizontal irradiance, or the DLS1 spectral irradiance corrected for the sun's angle ([`super::dls`]).
pub fn dls_irradiance(cap: &Capture) -> Result<Vec<f64>, RigError> {
    cap.bands.iter().map(|b| band_dls(b).map(|(e, _)| e)).collect()
}

/// One band's light-sensor irradiance and where it came from (for the import report).
pub fn band_dls(b: &super::calib::BandFile) -> Result<(f64, String), RigError> {
    if b.vendor == super::calib::Vendor::Dji {
        return match b.irradiance.filter(|e| *e > 0.0 && e.is_finite()) {
            Some(e) => Ok((e, "drone-dji:Irradiance (the sun sensor's units)".into())),
            None => Err(RigError::missing(
                &b.meta.path,
                "drone-dji:Irradiance",
                "--irradiance dls needs the sun sensor's irradiance (use --panel otherwise)",
            )),
        };
    }
    if let Some(d) = super::dls::dls2(b)? {
        return Ok((d.horizontal, format!("DLS2 {} x {} ({})", d.source, d.scale, d.scale_source)));
    }
    let x = &b.meta.xmp;
    if x.number("pix4d.com", "Irradiance").is_some() || x.number("micasense.com/DLS", "SpectralIrradiance").is_some() {
        // DLS1: the spectral irradiance at the tilted sensor, corrected for the sun's angle.
        return super::dls::dls1(b).map(|d| (d.horizontal, "DLS1 spectral irradiance, sun-angle corrected".into()));
    }
    Err(RigError::missing(
        &b.meta.path,
        "DLS:HorizontalIrradiance / Camera:Irradiance / drone-dji:Irradiance",
        "--irradiance dls needs the light sensor's irradiance (use --panel otherwise)",
    ))
}
