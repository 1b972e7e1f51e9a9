//! [`SpectralImage`]: a band-planar f32 image (`data[b·w·h + y·w + x]`) with one [`Band`] per plane.
//! Built from band-planar or pixel-interleaved buffers; the shape is checked on construction.

use super::{Band, OutputError, Result};

/// A B-band float image in band-planar order.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralImage {
    pub width: usize,
    pub height: usize,
    pub bands: Vec<Band>,
    /// `bands.len() × height × width` values, band-planar.
    pub data: Vec<f32>,
}

/// A band with a name and optional centre/FWHM (no data-layer scaling fields).
pub fn band(name: &str, center_nm: Option<f64>, fwhm_nm: Option<f64>) -> Band {
    Band { name: name.to_string(), center_nm, fwhm_nm, pixel_scale: None, black_level: None }
}

/// The six MS600Pro bands (450/555/660/720/750/840 nm) as spec/multispectral.md §5.1 lists them.
pub fn ms600pro_bands() -> Vec<Band> {
    [
        ("Blue", 450.0, 35.0),
        ("Green", 555.0, 27.0),
        ("Red", 660.0, 22.0),
        ("RedEdge1", 720.0, 10.0),
        ("RedEdge2", 750.0, 15.0),
        ("NIR", 840.0, 35.0),
    ]
    .iter()
    .map(|&(n, c, f)| band(n, Some(c), Some(f)))
    .collect()
}

impl SpectralImage {
    /// From a band-planar buffer.
    pub fn from_planar(width: usize, height: usize, bands: Vec<Band>, data: Vec<f32>) -> Result<Self> {
        check_shape(width, height, bands.len(), data.len())?;
        Ok(SpectralImage { width, height, bands, data })
    }

    /// From a pixel-interleaved buffer (`data[(y·w + x)·B + b]`).
    pub fn from_interleaved(width: usize, height: usize, bands: Vec<Band>, data: &[f32]) -> Result<Self> {
        let nb = bands.len();
        check_shape(width, height, nb, data.len())?;
        let n = width * height;
        let mut planar = vec![0.0f32; data.len()];
        for (p, px) in data.chunks_exact(nb).enumerate() {
            for (b, &v) in px.iter().enumerate() {
                planar[b * n + p] = v;
            }
        }
        Ok(SpectralImage { width, height, bands, data: planar })
    }

    /// A single-band image.
    pub fn single(width: usize, height: usize, band: Band, data: Vec<f32>) -> Result<Self> {
        Self::from_planar(width, height, vec![band], data)
    }

    /// Checks the shape (the fields are public, so a hand-built image may be inconsistent).
    pub fn validate(&self) -> Result<()> {
        check_shape(self.width, self.height, self.bands.len(), self.data.len())
    }

    pub fn n_bands(&self) -> usize {
        self.bands.len()
    }

    pub fn n_pixels(&self) -> usize {
        self.width * self.height
    }

    /// Plane `b`.
    pub fn band_data(&self, b: usize) -> &[f32] {
        let n = self.n_pixels();
        &self.data[b * n..(b + 1) * n]
    }

    /// Pixel-interleaved copy.
    pub fn to_interleaved(&self) -> Vec<f32> {
        let (n, nb) = (self.n_pixels(), self.n_bands());
        let mut out = vec![0.0f32; self.data.len()];
        for b in 0..nb {
            for (p, &v) in self.band_data(b).iter().enumerate() {
                out[p * nb + b] = v;
            }
        }
        debug_assert_eq!(out.len(), n * nb);
        out
    }

    /// Checks that `other` has the same width, height and band count (`what` names the argument).
    pub fn check_same_shape(&self, other: &SpectralImage, what: &str) -> Result<()> {
        self.validate()?;
        other.validate().map_err(|e| OutputError::invalid(what, e))?;
        if (self.width, self.height, self.n_bands()) != (other.width, other.height, other.n_bands()) {
            return Err(OutputError::invalid(
                what,
                format!(
                    "shape {}x{}x{} differs from {}x{}x{}",
                    other.width,
                    other.height,
                    other.n_bands(),
                    self.width,
                    self.height,
                    self.n_bands()
                ),
            ));
        }
        Ok(())
    }
}

fn check_shape(width: usize, height: usize, nb: usize, len: usize) -> Result<()> {
    if width == 0 || height == 0 || nb == 0 {
        return Err(OutputError::invalid("image", format!("empty shape {width}x{height} with {nb} bands")));
    }
    let want = width.checked_mul(height).and_then(|n| n.checked_mul(nb));
    if want != Some(len) {
        return Err(OutputError::invalid(
            "image",
            format!("{len} values do not make {width}x{height} pixels x {nb} bands"),
        ));
    }
    Ok(())
}

/// The band nearest to `nm` within `tol_nm` (by centre wavelength); `what` names the caller for the error.
pub fn nearest_band(bands: &[Band], nm: f64, tol_nm: f64, what: &str) -> Result<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, b) in bands.iter().enumerate() {
        if let Some(c) = b.center_nm {
            let d = (c - nm).abs();
            if d <= tol_nm && best.is_none_or(|(_, bd)| d < bd) {
                best = Some((i, d));
            }
        }
    }
    best.map(|(i, _)| i).ok_or_else(|| OutputError::MissingBand {
        what: what.to_string(),
        wavelength_nm: nm,
        tolerance_nm: tol_nm,
        available: describe_bands(bands),
    })
}

/// "Blue 450nm, Green 555nm, …" for error messages.
pub fn describe_bands(bands: &[Band]) -> String {
    if bands.is_empty() {
        return "none".into();
    }
    bands.iter().map(band_description).collect::<Vec<_>>().join(", ")
}

/// "NIR 840nm" (or the bare name when the centre is unknown): the GDAL band DESCRIPTION.
pub fn band_description(b: &Band) -> String {
    match b.center_nm {
        Some(c) => format!("{} {}nm", b.name, fmt_nm(c)),
        None => b.name.clone(),
    }
}

/// A wavelength without a trailing ".0" (840 → "840", 717.5 → "717.5").
pub fn fmt_nm(nm: f64) -> String {
    if nm.fract() == 0.0 && nm.abs() < 1e9 {
        format!("{}", nm as i64)
    } else {
        format!("{nm}")
    }
}

/// A band from a GDAL description such as `NIR 840nm` (name, then the centre wavelength when the last word is one).
pub fn band_from_description(d: &str) -> crate::data::Band {
    let mut words: Vec<&str> = d.split_whitespace().collect();
    let nm = words.last().and_then(|w| w.strip_suffix("nm")).and_then(|v| v.parse::<f64>().ok());
    if nm.is_some() {
        words.pop();
    }
    band(&words.join(" "), nm, None)
}
