//! Image metrics for evaluation: PSNR (data range a parameter, 1 for reflectance), SSIM in scikit-image's
//! Gaussian convention ([`ssim`]), per band and over all bands, with optional masks; and the `ns-eval`-style
//! JSON report ([`report`]); depth accuracy against ground-truth depth maps ([`depth`]).
//!
//! Conventions (nerfstudio's `get_image_metrics_and_images`, generalised to B bands):
//! - PSNR of an image = `10·log10(R² / MSE)` with the MSE over **all bands and pixels** (torchmetrics' PSNR on the
//!   whole tensor); per band, the MSE of that band. Identical images give `+inf`.
//! - SSIM of an image = the mean over bands of the per-band SSIM (skimage with `channel_axis`, torchmetrics).
//! - A mask (true = pixel counts) restricts the MSE to the masked pixels and the SSIM average to the masked
//!   pixels of the cropped SSIM map (the local windows still see unmasked neighbours).
//! - Computed in f64 from the f32 inputs.

pub mod depth;
pub mod lpips;
pub mod report;
pub mod ssim;

pub use report::{EvalReport, EvalResults, ViewEval};

use serde::Serialize;

use super::{OutputError, Result, SpectralImage};

/// Options shared by every metric.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetricOptions {
    /// Peak value for PSNR and the SSIM constants (skimage `data_range`); 1.0 for reflectance.
    pub data_range: f64,
}

impl Default for MetricOptions {
    fn default() -> Self {
        MetricOptions { data_range: 1.0 }
    }
}

/// Metrics of one band of one view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BandMetrics {
    #[serde(serialize_with = "report::finite_or_null")]
    pub psnr: f64,
    #[serde(serialize_with = "report::finite_or_null")]
    pub ssim: f64,
    #[serde(serialize_with = "report::finite_or_null")]
    pub mse: f64,
}

/// Metrics of one view: over all bands, and per band.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImageMetrics {
    /// PSNR of the MSE over all bands and (masked) pixels.
    #[serde(serialize_with = "report::finite_or_null")]
    pub psnr: f64,
    /// Mean over bands of the per-band SSIM.
    #[serde(serialize_with = "report::finite_or_null")]
    pub ssim: f64,
    #[serde(serialize_with = "report::finite_or_null")]
    pub mse: f64,
    pub bands: Vec<BandMetrics>,
}

/// `10·log10(R²/mse)`: `+inf` for mse 0.
pub fn psnr_from_mse(mse: f64, data_range: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (data_range * data_range / mse).log10()
    }
}

/// Mean squared error of two equal-length slices over the masked entries (NaN if the mask keeps none).
pub fn mse(a: &[f32], b: &[f32], mask: Option<&[bool]>) -> Result<f64> {
    if a.len() != b.len() {
        return Err(OutputError::invalid("mse", format!("{} values against {}", a.len(), b.len())));
    }
    if let Some(m) = mask {
        if m.len() != a.len() {
            return Err(OutputError::invalid("mask", format!("{} values for {} pixels", m.len(), a.len())));
        }
    }
    let (mut s, mut n) = (0.0f64, 0usize);
    for (i, (&p, &q)) in a.iter().zip(b).enumerate() {
        if mask.is_none_or(|m| m[i]) {
            let d = p as f64 - q as f64;
            s += d * d;
            n += 1;
        }
    }
    Ok(if n == 0 { f64::NAN } else { s / n as f64 })
}

/// PSNR of two equal-length slices (one band, or anything flattened).
pub fn psnr(a: &[f32], b: &[f32], mask: Option<&[bool]>, data_range: f64) -> Result<f64> {
    check_range(data_range)?;
    Ok(psnr_from_mse(mse(a, b, mask)?, data_range))
}

fn check_range(r: f64) -> Result<()> {
    if r > 0.0 && r.is_finite() {
        Ok(())
    } else {
        Err(OutputError::invalid("data_range", format!("must be positive and finite, got {r}")))
    }
}

/// Per-band and overall metrics of `pred` against `gt` (same shape). `mask` has one entry per pixel.
pub fn image_metrics(
    pred: &SpectralImage,
    gt: &SpectralImage,
    mask: Option<&[bool]>,
    opts: &MetricOptions,
) -> Result<ImageMetrics> {
    check_range(opts.data_range)?;
    gt.check_same_shape(pred, "pred")?;
    let (w, h) = (gt.width, gt.height);
    let mut bands = Vec::with_capacity(gt.n_bands());
    for b in 0..gt.n_bands() {
        let (p, g) = (pred.band_data(b), gt.band_data(b));
        let m = mse(p, g, mask)?;
        let s = ssim::ssim(p, g, w, h, mask, opts.data_range)?;
        bands.push(BandMetrics { psnr: psnr_from_mse(m, opts.data_range), ssim: s, mse: m });
    }
    let nb = bands.len() as f64;
    let mse_all = bands.iter().map(|b| b.mse).sum::<f64>() / nb;
    Ok(ImageMetrics {
        psnr: psnr_from_mse(mse_all, opts.data_range),
        ssim: bands.iter().map(|b| b.ssim).sum::<f64>() / nb,
        mse: mse_all,
        bands,
    })
}
