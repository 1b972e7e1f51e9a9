//! Each tree's attributes: the top's position and height, the terrain beneath, the crown's area and equivalent
//! diameter, and, given the orthomosaic on the same grid, the mean of every band over the crown and the vegetation
//! indices of those means (NDVI, NDRE) when the bands allow them. With NDVI known, a crown below
//! [`MIN_NDVI`] is not vegetation (a roof, a car) and is set apart.

use crate::output::raster::indices::{bands_for_index, DEFAULT_TOLERANCE_NM};
use crate::output::raster::VegetationIndex;
use crate::output::Band;
use crate::products::terrain::HeightGrid;

/// Below this NDVI a crown is not vegetation (green vegetation is above about 0.3; roofs, roads and soil below).
pub const MIN_NDVI: f64 = 0.3;

/// The orthomosaic over the CHM's grid: band-planar reflectance, NaN nodata.
#[derive(Debug, Clone)]
pub struct TreeBands {
    pub bands: Vec<Band>,
    pub data: Vec<f32>,
}

/// One tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    /// 1-based, as in the crown raster.
    pub id: u32,
    /// World x, y of the top's cell centre.
    pub x: f64,
    pub y: f64,
    /// Height above the terrain (the CHM at the top).
    pub height: f64,
    /// The terrain's height under the top (NaN without a DTM there).
    pub ground_z: f64,
    pub crown_area: f64,
    /// Diameter of the circle of the crown's area.
    pub crown_diameter: f64,
    /// Mean of each band over the crown (empty without an orthomosaic).
    pub band_means: Vec<f64>,
    pub ndvi: Option<f64>,
    pub ndre: Option<f64>,
    /// Share of the crown's cells the DSM measured or interpolated (None without a quality raster).
    pub support: Option<f64>,
    /// Training images that saw the top (None without the DSM's view counts).
    pub views: Option<f64>,
}

impl Tree {
    /// Whether the crown is vegetation: NDVI at least [`MIN_NDVI`], or unknown.
    pub fn is_vegetation(&self) -> bool {
        self.ndvi.is_none_or(|v| v >= MIN_NDVI)
    }
}

/// The trees of `tops` and their crowns `labels` ([`super::grow_crowns`]) on the CHM's grid, whose top-left corner
/// is world `origin`; `dtm` on the same grid, `bands` the orthomosaic's, `supported` the cells the DSM measured or
/// interpolated.
pub fn describe_trees(
    chm: &HeightGrid,
    dtm: Option<&HeightGrid>,
    origin: [f64; 2],
    (tops, labels): (&[usize], &[u32]),
    bands: Option<&TreeBands>,
    supported: Option<&[bool]>,
) -> Vec<Tree> {
    let (w, n) = (chm.width, chm.cells());
    let nb = bands.map_or(0, |b| b.bands.len());
    let mut area = vec![0usize; tops.len()];
    let mut sup = vec![0usize; tops.len()];
    let mut sums = vec![0.0f64; tops.len() * nb];
    let mut counts = vec![0usize; tops.len() * nb];
    for (cell, &l) in labels.iter().enumerate() {
        if l == 0 {
            continue;
        }
        let t = (l - 1) as usize;
        area[t] += 1;
        if supported.is_some_and(|s| s[cell]) {
            sup[t] += 1;
        }
        if let Some(b) = bands {
            for k in 0..nb {
                let v = b.data[k * n + cell];
                if v.is_finite() {
                    sums[t * nb + k] += v as f64;
                    counts[t * nb + k] += 1;
                }
            }
        }
    }
    // Each index's input bands, resolved once (None when the bands do not allow it).
    let inputs = |ix: VegetationIndex| bands.and_then(|b| bands_for_index(&b.bands, ix, DEFAULT_TOLERANCE_NM).ok());
    let (ndvi_bands, ndre_bands) = (inputs(VegetationIndex::Ndvi), inputs(VegetationIndex::Ndre720));
    let index = |ix: VegetationIndex, which: &Option<Vec<usize>>, means: &[f64]| -> Option<f64> {
        let v: Vec<f64> = which.as_ref()?.iter().map(|&k| means[k]).collect();
        Some(ix.formula(&v)).filter(|x| x.is_finite())
    };
    tops.iter()
        .enumerate()
        .map(|(t, &cell)| {
            let (r, c) = (cell / w, cell % w);
            let a = area[t] as f64 * chm.gsd * chm.gsd;
            let band_means: Vec<f64> = (0..nb)
                .map(|k| {
                    let i = t * nb + k;
                    if counts[i] > 0 {
                        sums[i] / counts[i] as f64
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            Tree {
                id: t as u32 + 1,
                x: origin[0] + (c as f64 + 0.5) * chm.gsd,
                y: origin[1] - (r as f64 + 0.5) * chm.gsd,
                height: chm.z[cell] as f64,
                ground_z: dtm.map_or(f64::NAN, |d| d.z[cell] as f64),
                crown_area: a,
                crown_diameter: 2.0 * (a / std::f64::consts::PI).sqrt(),
                ndvi: index(VegetationIndex::Ndvi, &ndvi_bands, &band_means),
                ndre: index(VegetationIndex::Ndre720, &ndre_bands, &band_means),
                views: None,
                support: supported.map(|_| if area[t] > 0 { sup[t] as f64 / area[t] as f64 } else { 0.0 }),
                band_means,
            }
        })
        .collect()
}
