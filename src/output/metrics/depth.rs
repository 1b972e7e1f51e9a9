//! Depth accuracy of rendered views against ground-truth depth maps (`msnerf eval --depth`, sweep columns).
//!
//! Conventions (issue 18):
//! - depths are distances along the unit ray in the dataset's units (metres); a `z` depth map is converted by the
//!   caller (ray distance = z · |camera-frame direction with z = 1|);
//! - error e = truth − prediction, so a **positive bias means the rendered surface lies in front of the true one**
//!   (towards the camera, i.e. above open ground for a nadir view);
//! - a pixel's footprint is depth / focal length (metres covered by one pixel at that depth), so "within 0.5 / 1
//!   footprint" is resolution-independent;
//! - pixels count when the truth is finite and positive and the mask (if any) keeps them; the prediction of a
//!   transparent ray (no crossing) still counts: a missing surface is an error, not an excluded pixel;
//! - the overall figures pool every counted pixel of every view (medians of pixels, not of per-view medians).

use serde::Serialize;

use super::report::finite_or_null;
use crate::output::compare::median;
use crate::output::{OutputError, Result};

/// Depth statistics of a set of pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DepthStats {
    pub pixels: usize,
    /// Median of |truth − prediction|.
    #[serde(serialize_with = "finite_or_null")]
    pub median_abs_error: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub mean_abs_error: f64,
    /// Median of truth − prediction (positive: in front of the surface).
    #[serde(serialize_with = "finite_or_null")]
    pub median_bias: f64,
    /// Median of (truth − prediction) / footprint.
    #[serde(serialize_with = "finite_or_null")]
    pub median_bias_footprints: f64,
    /// Fraction of pixels with |error| <= 0.5 footprint.
    #[serde(serialize_with = "finite_or_null")]
    pub within_half_footprint: f64,
    /// Fraction of pixels with |error| <= 1 footprint.
    #[serde(serialize_with = "finite_or_null")]
    pub within_one_footprint: f64,
    /// Median footprint (depth / focal length) of the counted pixels.
    #[serde(serialize_with = "finite_or_null")]
    pub median_footprint: f64,
}

/// Per-pixel errors of one view, kept for pooling.
#[derive(Debug, Clone, Default)]
pub struct DepthErrors {
    /// truth − prediction
    pub signed: Vec<f64>,
    /// depth / focal length of each counted pixel
    pub footprint: Vec<f64>,
}

impl DepthErrors {
    /// Errors of one view: `pred` and `truth` row-major distances along the ray, `focal_px` the focal length in
    /// pixels, `mask` (true = counts) optional.
    pub fn of_view(pred: &[f32], truth: &[f32], focal_px: f64, mask: Option<&[bool]>) -> Result<DepthErrors> {
        if pred.len() != truth.len() || mask.is_some_and(|m| m.len() != truth.len()) {
            return Err(OutputError::invalid(
                "depth map",
                format!(
                    "{} predicted, {} true depths{}",
                    pred.len(),
                    truth.len(),
                    mask.map(|m| format!(", {} mask pixels", m.len())).unwrap_or_default()
                ),
            ));
        }
        if !(focal_px.is_finite() && focal_px > 0.0) {
            return Err(OutputError::invalid("focal length", format!("{focal_px} is not a positive length")));
        }
        let mut e = DepthErrors::default();
        for (i, (&p, &t)) in pred.iter().zip(truth).enumerate() {
            if !(t.is_finite() && t > 0.0) || mask.is_some_and(|m| !m[i]) {
                continue;
            }
            // A non-finite prediction is as wrong as it gets: counted with an infinite error.
            let p = if p.is_finite() { p as f64 } else { f64::INFINITY };
            e.signed.push(t as f64 - p);
            e.footprint.push(t as f64 / focal_px);
        }
        Ok(e)
    }

    pub fn extend(&mut self, o: &DepthErrors) {
        self.signed.extend_from_slice(&o.signed);
        self.footprint.extend_from_slice(&o.footprint);
    }

    pub fn stats(&self) -> DepthStats {
        let n = self.signed.len();
        if n == 0 {
            let nan = f64::NAN;
            return DepthStats {
                pixels: 0,
                median_abs_error: nan,
                mean_abs_error: nan,
                median_bias: nan,
                median_bias_footprints: nan,
                within_half_footprint: nan,
                within_one_footprint: nan,
                median_footprint: nan,
            };
        }
        let abs: Vec<f64> = self.signed.iter().map(|e| e.abs()).collect();
        let rel: Vec<f64> = self.signed.iter().zip(&self.footprint).map(|(e, f)| e / f).collect();
        let within = |k: f64| rel.iter().filter(|r| r.abs() <= k).count() as f64 / n as f64;
        DepthStats {
            pixels: n,
            median_abs_error: median(&abs),
            mean_abs_error: abs.iter().sum::<f64>() / n as f64,
            median_bias: median(&self.signed),
            median_bias_footprints: median(&rel),
            within_half_footprint: within(0.5),
            within_one_footprint: within(1.0),
            median_footprint: median(&self.footprint),
        }
    }
}

/// One view's depth statistics.
#[derive(Debug, Clone, Serialize)]
pub struct ViewDepth {
    pub name: String,
    #[serde(flatten)]
    pub stats: DepthStats,
}

/// The depth part of an evaluation report.
#[derive(Debug, Clone, Serialize)]
pub struct DepthReport {
    /// Which rendered depth is compared (`median`: where the accumulation crosses 0.5).
    pub estimator: String,
    pub convention: String,
    pub overall: DepthStats,
    pub views: Vec<ViewDepth>,
}

impl DepthReport {
    /// Pools the views' errors.
    pub fn new(estimator: &str, views: &[(String, DepthErrors)]) -> DepthReport {
        let mut all = DepthErrors::default();
        for (_, e) in views {
            all.extend(e);
        }
        DepthReport {
            estimator: estimator.into(),
            convention: "error = true - rendered distance along the ray (metres); positive bias = in front of the \
                         surface; footprint = true depth / focal length"
                .into(),
            overall: all.stats(),
            views: views.iter().map(|(n, e)| ViewDepth { name: n.clone(), stats: e.stats() }).collect(),
        }
    }

    /// A short text table.
    pub fn table(&self) -> String {
        let o = &self.overall;
        format!(
            "depth ({}, {} px): median |err| {:.3} m, mean |err| {:.3} m, median bias {:+.3} m ({:+.2} footprints; \
             + = in front), within 0.5 / 1 footprint {:.1} % / {:.1} %, median footprint {:.3} m\n",
            self.estimator,
            o.pixels,
            o.median_abs_error,
            o.mean_abs_error,
            o.median_bias,
            o.median_bias_footprints,
            100.0 * o.within_half_footprint,
            100.0 * o.within_one_footprint,
            o.median_footprint
        )
    }
}
