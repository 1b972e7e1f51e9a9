//! `EvalReport`: the JSON `ns-eval` writes (`experiment_name, method_name, checkpoint, results{psnr, psnr_std,
//! ssim, ssim_std, lpips, lpips_std, num_rays_per_sec, num_rays_per_sec_std, fps, fps_std}`), plus `data_range`,
//! per-band summaries and per-view entries.
//!
//! - Means are over views; `_std` is the sample standard deviation (`torch.std`, n − 1), 0 for a single view.
//! - JSON has no infinity: a non-finite number (PSNR of identical images, std of infinite PSNRs, a mask that
//!   keeps nothing) is written as `null`.
//! - LPIPS is not computed here: `lpips` and `lpips_std` are `null` and `lpips_note` says why, unless a caller
//!   supplies per-view values through [`EvalReport::set_lpips`] (`msnerf eval --lpips-weights` does, with
//!   `super::lpips` on natural-colour composites).
//! - `num_rays_per_sec` = pixels / render seconds and `fps` = 1 / render seconds, per view, when timings are given;
//!   otherwise `null`.

use std::path::Path;

use serde::{Serialize, Serializer};

use super::ImageMetrics;
use crate::output::{atomic, Band, OutputError, Result};

/// Serialises non-finite floats as `null`.
pub fn finite_or_null<S: Serializer>(v: &f64, s: S) -> std::result::Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else {
        s.serialize_none()
    }
}

fn opt_finite_or_null<S: Serializer>(v: &Option<f64>, s: S) -> std::result::Result<S::Ok, S::Error> {
    match v {
        Some(x) if x.is_finite() => s.serialize_f64(*x),
        _ => s.serialize_none(),
    }
}

/// One evaluated view: its metrics, pixel count and (optionally) how long it took to render.
#[derive(Debug, Clone)]
pub struct ViewEval {
    pub name: String,
    pub metrics: ImageMetrics,
    /// Rays rendered for this view (width × height).
    pub num_rays: usize,
    pub render_seconds: Option<f64>,
}

/// `results` of `ns-eval`.
#[derive(Debug, Clone, Serialize)]
pub struct EvalResults {
    #[serde(serialize_with = "finite_or_null")]
    pub psnr: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub psnr_std: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub ssim: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub ssim_std: f64,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub lpips: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub lpips_std: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips_note: Option<String>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub num_rays_per_sec: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub num_rays_per_sec_std: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub fps: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub fps_std: Option<f64>,
}

/// Per-band means over views.
#[derive(Debug, Clone, Serialize)]
pub struct BandSummary {
    pub name: String,
    pub center_nm: Option<f64>,
    pub fwhm_nm: Option<f64>,
    #[serde(serialize_with = "finite_or_null")]
    pub psnr: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub psnr_std: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub ssim: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub ssim_std: f64,
}

/// One view in the report.
#[derive(Debug, Clone, Serialize)]
pub struct ViewEntry {
    pub name: String,
    #[serde(serialize_with = "finite_or_null")]
    pub psnr: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub ssim: f64,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub lpips: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub num_rays_per_sec: Option<f64>,
    #[serde(serialize_with = "opt_finite_or_null")]
    pub fps: Option<f64>,
    /// `{psnr, ssim, mse}` per band, in band order.
    pub bands: Vec<super::BandMetrics>,
}

/// The whole report.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub experiment_name: String,
    pub method_name: String,
    pub checkpoint: String,
    pub results: EvalResults,
    pub data_range: f64,
    pub num_views: usize,
    pub bands: Vec<BandSummary>,
    pub views: Vec<ViewEntry>,
    /// Depth accuracy (`msnerf eval --depth`), when the dataset has depth maps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth: Option<super::depth::DepthReport>,
}

/// Mean and sample standard deviation (n − 1; 0 for one value).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    if v.len() == 1 {
        return (mean, 0.0);
    }
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

const LPIPS_NOTE: &str =
    "not computed: LPIPS needs pretrained AlexNet weights (msnerf ships none): pass --lpips-weights FILE, see tools/export_lpips_weights.py";

impl EvalReport {
    /// Builds the report; every view must have one metric per band of `bands`.
    pub fn new(
        experiment_name: &str,
        method_name: &str,
        checkpoint: &str,
        bands: &[Band],
        views: &[ViewEval],
        data_range: f64,
    ) -> Result<EvalReport> {
        if views.is_empty() {
            return Err(OutputError::invalid("views", "no evaluated views"));
        }
        for v in views {
            if v.metrics.bands.len() != bands.len() {
                return Err(OutputError::invalid(
                    format!("view {}", v.name),
                    format!("{} band metrics for {} bands", v.metrics.bands.len(), bands.len()),
                ));
            }
        }
        let col = |f: &dyn Fn(&ViewEval) -> f64| views.iter().map(f).collect::<Vec<f64>>();
        let (psnr, psnr_std) = mean_std(&col(&|v| v.metrics.psnr));
        let (ssim, ssim_std) = mean_std(&col(&|v| v.metrics.ssim));
        let timed = views.iter().all(|v| v.render_seconds.is_some_and(|s| s > 0.0));
        let rate = |v: &ViewEval| v.render_seconds.filter(|s| *s > 0.0).map(|s| v.num_rays as f64 / s);
        let fps = |v: &ViewEval| v.render_seconds.filter(|s| *s > 0.0).map(|s| 1.0 / s);
        let (nrps, nrps_std, f, f_std) = if timed {
            let a = mean_std(&col(&|v| rate(v).unwrap_or(f64::NAN)));
            let b = mean_std(&col(&|v| fps(v).unwrap_or(f64::NAN)));
            (Some(a.0), Some(a.1), Some(b.0), Some(b.1))
        } else {
            (None, None, None, None)
        };
        let band_summaries = bands
            .iter()
            .enumerate()
            .map(|(b, band)| {
                let (p, ps) = mean_std(&col(&|v| v.metrics.bands[b].psnr));
                let (s, ss) = mean_std(&col(&|v| v.metrics.bands[b].ssim));
                BandSummary {
                    name: band.name.clone(),
                    center_nm: band.center_nm,
                    fwhm_nm: band.fwhm_nm,
                    psnr: p,
                    psnr_std: ps,
                    ssim: s,
                    ssim_std: ss,
                }
            })
            .collect();
        let entries = views
            .iter()
            .map(|v| ViewEntry {
                name: v.name.clone(),
                psnr: v.metrics.psnr,
                ssim: v.metrics.ssim,
                lpips: None,
                num_rays_per_sec: rate(v),
                fps: fps(v),
                bands: v.metrics.bands.clone(),
            })
            .collect();
        Ok(EvalReport {
            experiment_name: experiment_name.into(),
            method_name: method_name.into(),
            checkpoint: checkpoint.into(),
            results: EvalResults {
                psnr,
                psnr_std,
                ssim,
                ssim_std,
                lpips: None,
                lpips_std: None,
                lpips_note: Some(LPIPS_NOTE.into()),
                num_rays_per_sec: nrps,
                num_rays_per_sec_std: nrps_std,
                fps: f,
                fps_std: f_std,
            },
            data_range,
            num_views: views.len(),
            bands: band_summaries,
            views: entries,
            depth: None,
        })
    }

    /// The LPIPS hook: per-view LPIPS values (in view order) fill `lpips`, `lpips_std` and the view entries, and
    /// drop `lpips_note`.
    /// Sets per-view LPIPS values (and their mean and standard deviation); `note` says how they were computed.
    pub fn set_lpips_with_note(&mut self, per_view: &[f64], note: &str) -> Result<()> {
        self.set_lpips(per_view)?;
        self.results.lpips_note = Some(note.to_string());
        Ok(())
    }

    pub fn set_lpips(&mut self, per_view: &[f64]) -> Result<()> {
        if per_view.len() != self.views.len() {
            return Err(OutputError::invalid(
                "lpips",
                format!("{} values for {} views", per_view.len(), self.views.len()),
            ));
        }
        let (m, s) = mean_std(per_view);
        self.results.lpips = Some(m);
        self.results.lpips_std = Some(s);
        self.results.lpips_note = None;
        for (v, &l) in self.views.iter_mut().zip(per_view) {
            v.lpips = Some(l);
        }
        Ok(())
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("EvalReport serialises: plain numbers and strings")
    }

    /// Writes the JSON atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut s = self.to_json();
        s.push('\n');
        Ok(atomic::write_bytes(path, s.as_bytes())?)
    }

    /// A short text table: one row per band and the mean.
    pub fn table(&self) -> String {
        let f = |x: f64, p: usize| if x.is_finite() { format!("{x:.p$}") } else { "inf".into() };
        let mut s = format!("{:<20} {:>9} {:>8}\n", "band", "PSNR", "SSIM");
        for b in &self.bands {
            let name = match b.center_nm {
                Some(c) => format!("{} {}nm", b.name, crate::output::image::fmt_nm(c)),
                None => b.name.clone(),
            };
            s += &format!("{:<20} {:>9} {:>8}\n", name, f(b.psnr, 3), f(b.ssim, 4));
        }
        s += &format!("{:<20} {:>9} {:>8}\n", "all bands", f(self.results.psnr, 3), f(self.results.ssim, 4));
        if let Some(d) = &self.depth {
            s += &d.table();
        }
        s
    }
}
