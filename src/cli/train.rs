//! `msnerf train --data DIR --model M [--out RUN]`: trains a model on a dataset (see `msnerf::nerf::trainer`).

use super::Cli;
use crate::gpu::Context;
use crate::nerf::config::ModelConfig;
use crate::nerf::trainer::{train, TrainOptions};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Dataset folder (transforms.json with bands)
    #[arg(long)]
    pub data: PathBuf,
    /// Model: nerfacto, multispectral-nerf, tiny, or a YAML file
    #[arg(long, default_value = "nerfacto")]
    pub model: String,
    /// Run folder (default: runs/<dataset>-<model>)
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue from the run folder's latest checkpoint
    #[arg(long)]
    pub resume: bool,
    #[arg(long)]
    pub max_steps: Option<u64>,
    #[arg(long)]
    pub rays_per_batch: Option<usize>,
    /// Rays per GPU pass (bounds activation memory)
    #[arg(long)]
    pub rays_per_chunk: Option<usize>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop after this many seconds of training (the best held-out PSNR is reported)
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// Evaluate held-out PSNR every N steps
    #[arg(long)]
    pub eval_every: Option<u64>,
    /// Host memory for the training-image cache, in GiB
    #[arg(long, default_value_t = 8.0)]
    pub host_budget_gib: f64,
    /// Resample the resident training images every N steps when they do not all fit (paper §6.1)
    #[arg(long, default_value_t = 500)]
    pub resample_every: u64,
    /// Held-out pixels for the periodic evaluation
    #[arg(long, default_value_t = 4096)]
    pub eval_pixels: usize,
    /// No progress bar
    #[arg(long)]
    pub quiet: bool,
}

pub fn model_with_overrides(a: &TrainArgs) -> anyhow::Result<ModelConfig> {
    let mut m = ModelConfig::resolve(&a.model).map_err(anyhow::Error::msg)?;
    let t = &mut m.trainer;
    if let Some(v) = a.max_steps {
        t.max_steps = v;
    }
    if let Some(v) = a.rays_per_batch {
        t.rays_per_batch = v;
        t.rays_per_chunk = t.rays_per_chunk.min(v);
    }
    if let Some(v) = a.rays_per_chunk {
        t.rays_per_chunk = v;
    }
    if let Some(v) = a.seed {
        t.seed = v;
    }
    if let Some(v) = a.eval_every {
        t.steps_per_eval = v.max(1);
    }
    m.validate().map_err(|e| anyhow::anyhow!("after command-line overrides: {e}"))?;
    Ok(m)
}

pub fn run(cli: &Cli, a: &TrainArgs) -> anyhow::Result<()> {
    let model = model_with_overrides(a)?;
    let out = a.out.clone().unwrap_or_else(|| {
        let ds = a.data.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "data".into());
        PathBuf::from("runs").join(format!("{ds}-{}", model.name))
    });
    if out.join("checkpoints/latest.msnp").exists() && !a.resume {
        anyhow::bail!(
            "{} already holds a trained run: pass --resume to continue it, or choose another --out",
            out.display()
        );
    }
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let _ = ctrlc::set_handler(move || s2.store(true, std::sync::atomic::Ordering::Relaxed));
    let ctx = Context::new(&cli.context_desc())?;
    let opts = TrainOptions {
        data: a.data.clone(),
        model,
        out,
        resume: a.resume,
        time_budget_s: a.time_budget,
        host_budget_bytes: (a.host_budget_gib * (1u64 << 30) as f64) as u64,
        resample_every: a.resample_every,
        eval_pixels: a.eval_pixels,
        progress: !a.quiet,
        stop: Some(stop),
    };
    let s = train(&ctx, &opts).map_err(anyhow::Error::msg)?;
    println!(
        "trained {} steps in {:.1} s ({:.0} rays/s); train PSNR {:.2} dB; held-out PSNR {} -> best {}{}",
        s.steps,
        s.elapsed_s,
        s.rays_per_s,
        s.final_train_psnr,
        s.first_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or_else(|| "n/a".into()),
        s.best_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or_else(|| "n/a".into()),
        s.stopped_early.map(|w| format!(" (stopped: {w})")).unwrap_or_default()
    );
    println!("run folder: {}", s.run_dir.display());
    Ok(())
}
