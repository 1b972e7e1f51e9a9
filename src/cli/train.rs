//! `msnerf train --data DIR --model M [--out RUN]`: trains a model on a dataset (see `msnerf::nerf::trainer`).

use super::Cli;
use crate::gpu::Context;
use crate::nerf::config::{ActivationStorage, ModelConfig};
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
    /// Override the model's storage of MLP hidden activations (f16: half their memory; sums stay fp32)
    #[arg(long, value_enum)]
    pub mlp_activations: Option<ActivationStorage>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop after this many seconds of training (the best held-out PSNR is reported)
    #[arg(long, value_parser = super::positive_f64)]
    pub time_budget: Option<f64>,
    /// Train on these bands only: 0-based indices into the dataset's bands, comma-separated (e.g. 0,1,2)
    #[arg(long, value_delimiter = ',')]
    pub bands: Option<Vec<usize>>,
    /// Evaluate held-out PSNR every N steps
    #[arg(long)]
    pub eval_every: Option<u64>,
    /// Host memory for the training-image cache, in GiB
    #[arg(long, value_parser = super::positive_f64, default_value_t = 8.0)]
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
    /// Hardware profile (rtx2080ti-11gb, a100-80gb, lavapipe, a YAML file, or `auto`: this device's memory through
    /// the planner): ray counts and cache sizes from it; refuses before allocating when the plan does not fit.
    /// Explicit --rays-per-* flags still override the profile.
    #[arg(long)]
    pub hardware: Option<String>,
    /// Leave frames whose camera centre lies far outside the others out (they are listed) instead of refusing
    /// the dataset (model key `sampling.drop_outlier_cameras`)
    #[arg(long)]
    pub drop_outliers: bool,
    /// Ignore the dataset's `rig_cameras`: every band is taken as seen by the frame camera (model key
    /// `sampling.rig_cameras`)
    #[arg(long)]
    pub no_rig_cameras: bool,
    /// Train on the images alone: no depth supervision from the dataset's sparse points (the profiles use them
    /// when the dataset has them: model key `loss.depth`)
    #[arg(long)]
    pub images_only: bool,
}

pub fn model_with_overrides(a: &TrainArgs) -> anyhow::Result<ModelConfig> {
    apply_overrides(resolve_model(a)?, a)
}

/// The `--model` profile with the flags that change the model's memory (`--mlp-activations`): a hardware profile
/// sizes its chunks from this.
fn resolve_model(a: &TrainArgs) -> anyhow::Result<ModelConfig> {
    let mut m = ModelConfig::resolve(&a.model)?;
    if let Some(v) = a.mlp_activations {
        m.mlp_activations = v;
    }
    if a.drop_outliers {
        m.sampling.drop_outlier_cameras = true;
    }
    if a.no_rig_cameras {
        m.sampling.rig_cameras = false;
    }
    if a.images_only {
        m.loss.depth = None;
    }
    Ok(m)
}

/// The trainer flags (they win over a hardware profile's ray counts), then validation.
fn apply_overrides(mut m: ModelConfig, a: &TrainArgs) -> anyhow::Result<ModelConfig> {
    let t = &mut m.trainer;
    if let Some(v) = a.max_steps {
        t.max_steps = v;
    }
    if let Some(v) = a.rays_per_batch {
        t.set_rays_per_batch(v);
    }
    if let Some(v) = a.rays_per_chunk {
        t.set_rays_per_chunk(v);
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
    let mut model = model_with_overrides(a)?;
    let out = a.out.clone().unwrap_or_else(|| {
        let ds = a.data.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "data".into());
        PathBuf::from("runs").join(format!("{ds}-{}", model.name))
    });
    // A checkpoint is complete once its state (latest.json, written after the parameters) exists; `train-blocks` and
    // the Slurm script resume on the same file, so a run killed between the two writes starts over everywhere.
    if out.join("checkpoints/latest.json").exists() && !a.resume {
        anyhow::bail!(
            "{} already holds a trained run: pass --resume to continue it, or choose another --out",
            out.display()
        );
    }
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let _ = ctrlc::set_handler(move || s2.store(true, std::sync::atomic::Ordering::Relaxed));
    let ctx = Context::new(&cli.context_desc())?;
    let (mut host_budget_bytes, mut resample_every) =
        ((a.host_budget_gib * (1u64 << 30) as f64) as u64, a.resample_every);
    if let Some(h) = &a.hardware {
        let base = resolve_model(a)?;
        let ds = crate::nerf::trainer::load_run_dataset(&a.data, a.bands.as_deref(), &base.sampling)?;
        let mut override_err = None;
        let fitted = crate::plan::train::fit_training(&ctx, h, base.clone(), &ds, |m| match apply_overrides(m, a) {
            Ok(m) => Ok(m),
            Err(e) => {
                override_err = Some(e);
                Ok(base)
            }
        })?;
        if let Some(e) = override_err {
            return Err(e);
        }
        host_budget_bytes = fitted.host_budget_bytes;
        resample_every = fitted.resample_every.unwrap_or(resample_every);
        eprintln!("{}", fitted.describe());
        model = fitted.model;
    }
    let opts = TrainOptions {
        data: a.data.clone(),
        model,
        out,
        resume: a.resume,
        time_budget_s: a.time_budget,
        host_budget_bytes,
        resample_every,
        eval_pixels: a.eval_pixels,
        progress: !a.quiet,
        stop: Some(stop),
        bands: a.bands.clone(),
    };
    let s = train(&ctx, &opts)?;
    println!(
        "trained {} steps in {:.1} s ({:.0} rays/s, {:.0} ms/step); train PSNR {:.2} dB; held-out PSNR {} at the first \
         evaluation, best {}{}{}",
        s.steps,
        s.elapsed_s,
        s.rays_per_s,
        s.mean_step_ms,
        s.final_train_psnr,
        s.first_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or_else(|| "n/a".into()),
        s.best_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or_else(|| "n/a".into()),
        s.best_eval_step.map(|v| format!(" at step {v}")).unwrap_or_default(),
        s.stopped_early.map(|w| format!(" (stopped: {w})")).unwrap_or_default()
    );
    println!("depth supervision: {}", s.depth_supervision);
    for n in &s.notes {
        println!("warning: {n}");
    }
    println!("run folder: {}", s.run_dir.display());
    Ok(())
}
