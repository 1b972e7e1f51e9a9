//! The Slurm time limit of a block's task from measurements (`partition --slurm --slurm-time-from BENCH.json`):
//! `msnerf bench train --json`, run on the cluster's GPU kind, gives the milliseconds per training step of each
//! model profile, band count and batch. The limit is
//!
//! `steps x ms_per_step x 1.25 + 15 minutes`, rounded up to whole minutes,
//!
//! where the steps and the model come from the blocks' `msnerf train` arguments (`--max-steps`, `--model`,
//! `--rays-per-batch`; otherwise the profile's). The 25 % covers evaluations, checkpoints and the batch sampling the
//! benchmark's steady state leaves out; the 15 minutes cover loading the images and the final evaluation. The
//! measurement used is the one for the profile and the batch with the dataset's band count, or the nearest larger
//! band count measured (more bands never make a step faster).

use std::path::Path;

use super::error::ScaleError;

/// Safety factor on the measured step time.
pub const STEP_MARGIN: f64 = 1.25;
/// Minutes added for loading, evaluation and saving.
pub const FIXED_MINUTES: f64 = 15.0;

/// A time limit and what it was computed from.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeEstimate {
    pub model: String,
    pub steps: u64,
    pub rays_per_batch: usize,
    /// Band count of the measurement used.
    pub bench_bands: usize,
    pub ms_per_step: f64,
    /// The measurement's device.
    pub device: String,
    pub minutes: u64,
    /// `--time` for Slurm: `HH:MM:00` or `D-HH:MM:00`.
    pub limit: String,
}

/// The value of `--key V` or `--key=V` in `args` (the last one given).
fn arg_value<'a>(args: &'a [String], key: &str) -> Option<&'a str> {
    let mut v = None;
    for (i, a) in args.iter().enumerate() {
        if a == key {
            v = args.get(i + 1).map(String::as_str);
        } else if let Some(rest) = a.strip_prefix(key).and_then(|r| r.strip_prefix('=')) {
            v = Some(rest);
        }
    }
    v
}

/// Slurm's `--time` for `minutes`.
pub fn slurm_limit(minutes: u64) -> String {
    let (d, h, m) = (minutes / 1440, minutes % 1440 / 60, minutes % 60);
    if d > 0 {
        format!("{d}-{h:02}:{m:02}:00")
    } else {
        format!("{h:02}:{m:02}:00")
    }
}

/// The time limit for training `bands`-band blocks with `train_args`, from the `bench train --json` file `bench`.
pub fn estimate(bench: &Path, train_args: &[String], bands: usize) -> Result<TimeEstimate, ScaleError> {
    let bad = |reason: String| ScaleError::Dataset { path: bench.to_path_buf(), reason };
    let model = arg_value(train_args, "--model").unwrap_or("nerfacto");
    let cfg = crate::nerf::config::ModelConfig::resolve(model)
        .map_err(|e| ScaleError::option("--model (after --)", e.to_string()))?;
    let number = |key: &str| -> Result<Option<u64>, ScaleError> {
        arg_value(train_args, key)
            .map(|v| v.parse::<u64>().map_err(|_| ScaleError::option(key, format!("`{v}` is not a count"))))
            .transpose()
    };
    let steps = number("--max-steps")?.unwrap_or(cfg.trainer.max_steps);
    let rays = number("--rays-per-batch")?.map_or(cfg.trainer.rays_per_batch, |v| v as usize);
    let text = std::fs::read_to_string(bench).map_err(|e| bad(e.to_string()))?;
    let rows: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not `msnerf bench train --json` output: {e}")))?;
    let rows = rows.as_array().ok_or_else(|| bad("not `msnerf bench train --json` output (a list)".into()))?;
    let mut measured = Vec::new();
    let mut best: Option<(usize, f64, String)> = None;
    for (i, r) in rows.iter().enumerate() {
        let (Some(m), Some(b), Some(n), Some(ms)) =
            (r["model"].as_str(), r["bands"].as_u64(), r["rays_per_batch"].as_u64(), r["ms_per_step"].as_f64())
        else {
            return Err(bad(format!("entry {i} lacks model, bands, rays_per_batch or ms_per_step")));
        };
        if !(ms.is_finite() && ms > 0.0) {
            return Err(bad(format!("entry {i}: ms_per_step {ms} is not a time")));
        }
        measured.push(format!("{m} at {b} bands, {n} rays"));
        let b = b as usize;
        if m == cfg.name && n as usize == rays && b >= bands && best.as_ref().is_none_or(|x| b < x.0) {
            best = Some((b, ms, r["device"].as_str().unwrap_or("?").to_string()));
        }
    }
    let Some((bench_bands, ms, device)) = best else {
        return Err(bad(format!(
            "no measurement of {} at {rays} rays per batch with {bands} or more bands (it has: {}); run `msnerf bench \
             train --models {} --bands {bands} --rays-per-batch {rays} --json` on the cluster's GPU",
            cfg.name,
            if measured.is_empty() { "nothing".to_string() } else { measured.join("; ") },
            cfg.name
        )));
    };
    let minutes = (steps as f64 * ms * STEP_MARGIN / 60_000.0 + FIXED_MINUTES).ceil() as u64;
    Ok(TimeEstimate {
        model: cfg.name,
        steps,
        rays_per_batch: rays,
        bench_bands,
        ms_per_step: ms,
        device,
        minutes,
        limit: slurm_limit(minutes),
    })
}
