//! What a sweep measures per cell (`OUT/cells/<id>/result.json`): the settings, the training cost (time per step with
//! its per-kernel breakdown, peak GPU and host-cache bytes) and held-out PSNR/SSIM per band at each wall-clock point.
//! A cell is done exactly when its result file exists and reads back with the same budget.

use super::error::SweepError;
use crate::util::atomic;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Held-out metrics of one band (or of all bands: `name` = "mean").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BandScore {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
}

/// One evaluation of the held-out views after `elapsed_s` seconds of training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimePoint {
    /// The wall-clock point asked for (the budget's end for the last one).
    pub target_s: f64,
    /// Training seconds actually done (a step is never cut, so slightly past the target).
    pub elapsed_s: f64,
    pub step: u64,
    /// PSNR of the MSE over all bands (mean over views); SSIM the mean over bands and views.
    pub psnr: f64,
    pub ssim: f64,
    pub bands: Vec<BandScore>,
    /// Depth and point-cloud accuracy, when the dataset has depth maps and a `ground_truth.ply` (the simulator's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<GeometryScore>,
}

/// Geometry at one evaluation point: the held-out views' median depth against their depth maps
/// (`output::metrics::depth` conventions: + = in front of the surface) and the default careful point-cloud export
/// against the ground-truth cloud (`output::compare`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GeometryScore {
    pub depth_median_abs_m: Option<f64>,
    pub depth_bias_m: Option<f64>,
    pub depth_bias_footprints: Option<f64>,
    pub depth_within_half_footprint: Option<f64>,
    pub depth_within_one_footprint: Option<f64>,
    pub median_footprint_m: Option<f64>,
    pub cloud_points: Option<usize>,
    /// Median distance of the cloud's points to the ground truth (accuracy).
    pub cloud_accuracy_median_m: Option<f64>,
    /// Median distance of the ground truth to the cloud (completeness).
    pub cloud_completeness_median_m: Option<f64>,
    /// F-score at `cloud_threshold_m`.
    pub cloud_f_score: Option<f64>,
    pub cloud_threshold_m: Option<f64>,
    pub cloud_rmse_planar_m: Option<f64>,
    pub cloud_rmse_vertical_m: Option<f64>,
    pub cloud_median_signed_dz_m: Option<f64>,
    /// The paper's standard (planar RMSE <= 0.3 m, vertical RMSE <= 0.5 m) met.
    pub standard_pass: Option<bool>,
}

/// Mean time of one kernel per training step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelShare {
    pub name: String,
    pub calls_per_step: f64,
    pub ms_per_step: f64,
}

/// Everything measured for one cell.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellResult {
    pub id: String,
    pub index: usize,
    /// `key=value, ...` as the grid sets it.
    pub label: String,
    /// The cell's settings as (key, value shown as text), in axis order.
    pub values: Vec<(String, String)>,
    pub model: String,
    pub band_names: Vec<String>,
    pub budget_time_s: Option<f64>,
    pub budget_steps: Option<u64>,
    pub steps: u64,
    pub elapsed_s: f64,
    pub mean_step_ms: f64,
    pub gpu_ms_per_step: f64,
    pub kernels: Vec<KernelShare>,
    pub peak_gpu_bytes: u64,
    pub peak_cache_bytes: u64,
    pub parameters: u64,
    pub points: Vec<TimePoint>,
    /// Best held-out PSNR of the trainer's own pixel-sample check (`msnerf train` reports the same number).
    pub trainer_best_eval_psnr: Option<f64>,
    /// Why training ended: the time budget, the step budget.
    pub stopped: String,
}

impl CellResult {
    /// The last evaluation (the model at the end of its budget).
    pub fn final_point(&self) -> Option<&TimePoint> {
        self.points.last()
    }

    /// The evaluated point with the best held-out PSNR among those asked for at or before `seconds` of training.
    pub fn best_within(&self, seconds: f64) -> Option<&TimePoint> {
        self.points
            .iter()
            .filter(|p| p.target_s <= seconds + 1e-9 && p.psnr.is_finite())
            .max_by(|a, b| a.psnr.total_cmp(&b.psnr))
    }

    pub fn write(&self, path: &Path) -> Result<(), SweepError> {
        let s = serde_json::to_string_pretty(self).map_err(|e| SweepError::file(path, e))?;
        atomic::write_bytes(path, s.as_bytes()).map_err(|e| SweepError::file(&e.path, e.reason))
    }

    pub fn read(path: &Path) -> Result<CellResult, SweepError> {
        let s = std::fs::read_to_string(path).map_err(|e| SweepError::file(path, e))?;
        serde_json::from_str(&s).map_err(|e| SweepError::file(path, e))
    }
}
