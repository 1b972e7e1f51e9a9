//! What a sweep measures per cell (`OUT/cells/<id>/result.json`): the settings, the training cost (time per step with
//! its per-kernel breakdown, peak GPU and host-cache bytes) and held-out PSNR/SSIM per band at each wall-clock point.
//! A cell is done exactly when its result file exists and reads back with the same budget.

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

    pub fn write(&self, path: &Path) -> Result<(), String> {
        let s = serde_json::to_string_pretty(self).map_err(|e| e.to_string())?;
        atomic::write_bytes(path, s.as_bytes()).map_err(|e| e.to_string())
    }

    pub fn read(path: &Path) -> Result<CellResult, String> {
        let s = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_str(&s).map_err(|e| format!("{}: {e}", path.display()))
    }
}
