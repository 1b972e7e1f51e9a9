//! Vegetation indices by name, from **reflectance** bands picked by centre wavelength (spec/multispectral.md §5.1).
//!
//! Each input is the band whose centre is nearest the index's nominal wavelength, within a tolerance
//! (default [`DEFAULT_TOLERANCE_NM`] = 25 nm); otherwise an error names the index and the missing wavelength.
//! Two inputs may not resolve to the same band. Values are computed in f64 and stored as f32; a zero
//! denominator (or a NaN input) gives NaN, which is also the GeoTIFF nodata.
//!
//! | name | formula | nominal nm |
//! |---|---|---|
//! | NDVI | (NIR − R)/(NIR + R) | 840, 660 |
//! | NDRE720 / NDRE750 | (NIR − RE)/(NIR + RE) | 840, 720 / 750 |
//! | GNDVI | (NIR − G)/(NIR + G) | 840, 555 |
//! | SAVI | 1.5·(NIR − R)/(NIR + R + 0.5) | 840, 660 |
//! | OSAVI | (NIR − R)/(NIR + R + 0.16) (without the ×1.16 of some definitions) | 840, 660 |
//! | EVI | 2.5·(NIR − R)/(NIR + 6R − 7.5B + 1) | 840, 660, 450 |
//! | NDWI (McFeeters) | (G − NIR)/(G + NIR) | 555, 840 |
//! | CI_rededge | NIR/RE − 1 | 840, 720 |
//! | CI_green | NIR/G − 1 | 840, 555 |
//! | MTCI | (R750 − R710)/(R710 − R680) | 750, 710, 680 (MS600Pro: RE2, RE1, R) |
//! | NDVI705 | (R750 − R705)/(R750 + R705) | 750, 705 (MS600Pro: RE2, RE1) |

use std::path::Path;

use super::geotiff::{write_geotiff, GeoReference, GeoTiffOptions};
use crate::output::image::{band, nearest_band};
use crate::output::Band;
use crate::output::{OutputError, Result, SpectralImage};

pub const DEFAULT_TOLERANCE_NM: f64 = 25.0;

/// The supported indices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VegetationIndex {
    Ndvi,
    Ndre720,
    Ndre750,
    Gndvi,
    Savi,
    Osavi,
    Evi,
    Ndwi,
    CiRededge,
    CiGreen,
    Mtci,
    Ndvi705,
}

impl VegetationIndex {
    pub const ALL: [VegetationIndex; 12] = [
        VegetationIndex::Ndvi,
        VegetationIndex::Ndre720,
        VegetationIndex::Ndre750,
        VegetationIndex::Gndvi,
        VegetationIndex::Savi,
        VegetationIndex::Osavi,
        VegetationIndex::Evi,
        VegetationIndex::Ndwi,
        VegetationIndex::CiRededge,
        VegetationIndex::CiGreen,
        VegetationIndex::Mtci,
        VegetationIndex::Ndvi705,
    ];

    /// The canonical name ("NDVI", "CI_rededge", …).
    pub fn name(self) -> &'static str {
        use VegetationIndex::*;
        match self {
            Ndvi => "NDVI",
            Ndre720 => "NDRE720",
            Ndre750 => "NDRE750",
            Gndvi => "GNDVI",
            Savi => "SAVI",
            Osavi => "OSAVI",
            Evi => "EVI",
            Ndwi => "NDWI",
            CiRededge => "CI_rededge",
            CiGreen => "CI_green",
            Mtci => "MTCI",
            Ndvi705 => "NDVI705",
        }
    }

    /// Case-insensitive lookup by name.
    pub fn parse(name: &str) -> Result<VegetationIndex> {
        Self::ALL.iter().copied().find(|i| i.name().eq_ignore_ascii_case(name)).ok_or_else(|| {
            let all: Vec<&str> = Self::ALL.iter().map(|i| i.name()).collect();
            OutputError::invalid(format!("index `{name}`"), format!("unknown; known: {}", all.join(", ")))
        })
    }

    /// Nominal input wavelengths in the order [`VegetationIndex::formula`] takes them.
    pub fn wavelengths(self) -> &'static [f64] {
        use VegetationIndex::*;
        match self {
            Ndvi | Savi | Osavi => &[840.0, 660.0],
            Ndre720 | CiRededge => &[840.0, 720.0],
            Ndre750 => &[840.0, 750.0],
            Gndvi | CiGreen => &[840.0, 555.0],
            Evi => &[840.0, 660.0, 450.0],
            Ndwi => &[555.0, 840.0],
            Mtci => &[750.0, 710.0, 680.0],
            Ndvi705 => &[750.0, 705.0],
        }
    }

    /// The index of inputs `v` (in [`VegetationIndex::wavelengths`] order); NaN for a zero denominator.
    pub fn formula(self, v: &[f64]) -> f64 {
        use VegetationIndex::*;
        let ratio = |num: f64, den: f64| if den == 0.0 { f64::NAN } else { num / den };
        match self {
            Ndvi | Ndre720 | Ndre750 | Gndvi | Ndwi | Ndvi705 => ratio(v[0] - v[1], v[0] + v[1]),
            Savi => 1.5 * ratio(v[0] - v[1], v[0] + v[1] + 0.5),
            Osavi => ratio(v[0] - v[1], v[0] + v[1] + 0.16),
            Evi => 2.5 * ratio(v[0] - v[1], v[0] + 6.0 * v[1] - 7.5 * v[2] + 1.0),
            CiRededge | CiGreen => ratio(v[0], v[1]) - 1.0,
            Mtci => ratio(v[0] - v[1], v[1] - v[2]),
        }
    }

    /// Display range for the colour-mapped preview.
    pub fn preview_range(self) -> (f64, f64) {
        use VegetationIndex::*;
        match self {
            CiRededge | CiGreen => (0.0, 10.0),
            Mtci => (0.0, 6.0),
            _ => (-1.0, 1.0),
        }
    }
}

/// The band index for each input of `index` in `img` (errors name the index and the wavelength).
pub fn index_bands(img: &SpectralImage, index: VegetationIndex, tol_nm: f64) -> Result<Vec<usize>> {
    bands_for_index(&img.bands, index, tol_nm)
}

/// [`index_bands`] from a band list alone (flags are checked before anything is rendered).
pub fn bands_for_index(bands: &[Band], index: VegetationIndex, tol_nm: f64) -> Result<Vec<usize>> {
    let what = format!("index {}", index.name());
    let idx =
        index.wavelengths().iter().map(|&nm| nearest_band(bands, nm, tol_nm, &what)).collect::<Result<Vec<usize>>>()?;
    for i in 0..idx.len() {
        for j in i + 1..idx.len() {
            if idx[i] == idx[j] {
                return Err(OutputError::invalid(
                    what,
                    format!(
                        "{} nm and {} nm both resolve to band {} ({}); it needs distinct bands",
                        index.wavelengths()[i],
                        index.wavelengths()[j],
                        idx[i],
                        bands[idx[i]].name
                    ),
                ));
            }
        }
    }
    Ok(idx)
}

/// The index per pixel.
pub fn compute_index(img: &SpectralImage, index: VegetationIndex, tol_nm: f64) -> Result<Vec<f32>> {
    img.validate()?;
    let idx = index_bands(img, index, tol_nm)?;
    let planes: Vec<&[f32]> = idx.iter().map(|&b| img.band_data(b)).collect();
    let mut v = vec![0.0f64; planes.len()];
    Ok((0..img.n_pixels())
        .map(|p| {
            for (k, plane) in planes.iter().enumerate() {
                v[k] = plane[p] as f64;
            }
            index.formula(&v) as f32
        })
        .collect())
}

/// The index as a single-band image (band named after the index, no centre wavelength).
pub fn index_image(img: &SpectralImage, index: VegetationIndex, tol_nm: f64) -> Result<SpectralImage> {
    SpectralImage::single(img.width, img.height, band(index.name(), None, None), compute_index(img, index, tol_nm)?)
}

/// Computes the index and writes it as a single-band float32 GeoTIFF with NaN nodata; returns the values.
pub fn write_index_geotiff(
    path: &Path,
    img: &SpectralImage,
    index: VegetationIndex,
    tol_nm: f64,
    georef: Option<GeoReference>,
) -> Result<SpectralImage> {
    let out = index_image(img, index, tol_nm)?;
    let bands_used = index_bands(img, index, tol_nm)?
        .iter()
        .map(|&b| crate::output::image::band_description(&img.bands[b]))
        .collect::<Vec<_>>()
        .join(", ");
    let opts = GeoTiffOptions {
        nodata: Some(f64::NAN),
        georef,
        bigtiff: None,
        metadata: vec![("INDEX".into(), index.name().into()), ("INDEX_BANDS".into(), bands_used)],
    };
    write_geotiff(path, &out, &opts)?;
    Ok(out)
}
