//! `msnerf partition DATASET --blocks AxB --overlap F --out BLOCKS` and `msnerf train-blocks BLOCKS`: thin CLI over
//! [`crate::scale`].

use std::path::PathBuf;

use crate::scale::partition::{parse_grid, partition_dataset, PartitionOptions};
use crate::scale::runner::{train_blocks, TrainBlocksOptions};

#[derive(clap::Args, Debug)]
pub struct PartitionArgs {
    /// Dataset folder (transforms.json)
    pub dataset: PathBuf,
    /// Blocks along x and y of the ground area (levelled world frame), e.g. 2x2
    #[arg(long)]
    pub blocks: String,
    /// Each block grown on every side by this fraction of its size, in [0, 1)
    #[arg(long, value_parser = super::finite_f64, default_value_t = 0.15)]
    pub overlap: f64,
    /// Ground height in the levelled frame: world z for a dataset with a `crs`, otherwise the height along the
    /// cameras' mean up; default: where the cameras' optical axes meet (a nadir grid flight needs it given)
    #[arg(long, value_parser = super::finite_f64)]
    pub ground_z: Option<f64>,
    /// Output folder: blocks.json and one dataset per block (must not exist unless --overwrite)
    #[arg(long)]
    pub out: PathBuf,
    /// Replace OUT when it exists
    #[arg(long)]
    pub overwrite: bool,
    /// Also write OUT/slurm.sh: a Slurm job array, one task per block (`sbatch OUT/slurm.sh`)
    #[arg(long)]
    pub slurm: bool,
    /// Time limit of each Slurm task [default: 08:00:00]
    #[arg(long, conflicts_with = "slurm_time_from")]
    pub slurm_time: Option<String>,
    /// Compute each task's time limit from `msnerf bench train --json` output measured on the cluster's GPU kind:
    /// steps x ms per step x 1.25 + 15 min, for the model, batch and band count of the training arguments
    #[arg(long)]
    pub slurm_time_from: Option<PathBuf>,
    /// Generic resources per Slurm task (`gpu:1`, `gpu:a100:1`...); `none` for CPU-only nodes
    #[arg(long, default_value = "gpu:1")]
    pub slurm_gres: String,
    /// CPUs per Slurm task
    #[arg(long, default_value_t = 4)]
    pub slurm_cpus: usize,
    /// Host memory for each task's image cache, in GiB (`msnerf train --host-budget-gib`)
    #[arg(long, value_parser = super::positive_f64, default_value_t = 8.0)]
    pub host_budget_gib: f64,
    /// Arguments for every block's `msnerf train` in the Slurm script (after `--`)
    #[arg(last = true)]
    pub train_args: Vec<String>,
}

#[derive(clap::Args, Debug)]
pub struct TrainBlocksArgs {
    /// Folder written by `msnerf partition`
    pub blocks: PathBuf,
    /// Blocks trained at once
    #[arg(long, default_value_t = 1)]
    pub parallel: usize,
    /// Vulkan devices handed out round robin, comma-separated (`msnerf devices` indices or names)
    #[arg(long, value_delimiter = ',')]
    pub devices: Vec<String>,
    /// Arguments for every `msnerf train` (after `--`), e.g. `-- --model nerfacto --max-steps 30000`
    #[arg(last = true)]
    pub train_args: Vec<String>,
}

/// The arguments after `--` as `msnerf train` will parse them for each block (which adds its own `--data`, `--out`,
/// `--quiet` and, when resuming, `--resume`): refused before anything runs or is written.
fn check_train_args(train_args: &[String]) -> anyhow::Result<()> {
    use clap::Parser;
    for own in ["--data", "--out", "--quiet", "--resume"] {
        if train_args.iter().any(|t| t == own || t.starts_with(&format!("{own}="))) {
            anyhow::bail!("arguments after `--`: {own} is set for each block by msnerf itself");
        }
    }
    let argv = ["msnerf", "train", "--data", "BLOCK", "--out", "RUN", "--quiet"].into_iter().map(String::from);
    match super::Cli::try_parse_from(argv.chain(train_args.iter().cloned())) {
        Ok(_) => Ok(()),
        Err(e) => {
            let first = e.to_string().lines().next().unwrap_or_default().trim_start_matches("error: ").to_string();
            anyhow::bail!("arguments after `--` for `msnerf train`: {first}")
        }
    }
}

pub fn run_partition(a: &PartitionArgs) -> anyhow::Result<()> {
    check_train_args(&a.train_args)?;
    anyhow::ensure!(
        a.slurm || (a.slurm_time.is_none() && a.slurm_time_from.is_none()),
        "--slurm-time and --slurm-time-from need --slurm"
    );
    let ds = crate::data::load_dataset(&a.dataset, &crate::data::LoadOptions::default())?;
    // The time limit before anything is written.
    let time = match (&a.slurm_time, &a.slurm_time_from) {
        (_, Some(bench)) if a.slurm => {
            let bands = ds.n_bands();
            let e = crate::scale::slurm_time::estimate(bench, &a.train_args, bands)?;
            println!(
                "Slurm time limit {}: {} steps of {} at {} rays x {:.1} ms ({} bands measured on {}) x {} + {} min",
                e.limit,
                e.steps,
                e.model,
                e.rays_per_batch,
                e.ms_per_step,
                e.bench_bands,
                e.device,
                crate::scale::slurm_time::STEP_MARGIN,
                crate::scale::slurm_time::FIXED_MINUTES
            );
            e.limit
        }
        (Some(t), _) => t.clone(),
        _ => "08:00:00".to_string(),
    };
    // Every Slurm option is checked before anything is written; the script goes into the blocks folder before it
    // is renamed into place, so the folder appears complete or not at all.
    let slurm = if a.slurm {
        crate::scale::slurm::check_time(&time)?;
        anyhow::ensure!(
            a.host_budget_gib.is_finite() && a.host_budget_gib > 0.0,
            "--host-budget-gib must be > 0, got {}",
            a.host_budget_gib
        );
        Some(crate::scale::slurm::SlurmOptions {
            time: time.clone(),
            host_budget_bytes: (a.host_budget_gib * (1u64 << 30) as f64) as u64,
            cpus_per_task: a.slurm_cpus,
            gres: if a.slurm_gres == "none" { String::new() } else { a.slurm_gres.clone() },
            exe: std::env::current_exe()?,
            train_args: a.train_args.clone(),
        })
    } else {
        None
    };
    let o = PartitionOptions {
        blocks: parse_grid(&a.blocks)?,
        overlap: a.overlap,
        ground_z: a.ground_z,
        overwrite: a.overwrite,
    };
    let (b, gib) = partition_dataset(&ds, &a.out, &o, slurm.as_ref())?;
    println!(
        "wrote {}: {} blocks ({}x{}), overlap {}",
        a.out.display(),
        b.blocks.len(),
        b.grid[0],
        b.grid[1],
        b.overlap
    );
    for blk in &b.blocks {
        println!(
            "  {}: x {:.2}..{:.2}, y {:.2}..{:.2} (core); {} training and {} eval views",
            blk.name, blk.core[0], blk.core[1], blk.core[2], blk.core[3], blk.train_frames, blk.eval_frames
        );
    }
    for w in &b.warnings {
        println!("warning: {w}");
    }
    if let Some(gib) = gib {
        println!(
            "Slurm job array: sbatch {} ({} tasks, {gib} GiB each)",
            a.out.join("slurm.sh").display(),
            b.blocks.len()
        );
    }
    Ok(())
}

pub fn run_train_blocks(a: &TrainBlocksArgs) -> anyhow::Result<()> {
    check_train_args(&a.train_args)?;
    let o = TrainBlocksOptions {
        exe: std::env::current_exe()?,
        parallel: a.parallel,
        devices: a.devices.clone(),
        train_args: a.train_args.clone(),
    };
    let runs = train_blocks(&a.blocks, &o)?;
    for r in &runs {
        let steps = r.steps.map_or("-".to_string(), |s| s.to_string());
        let how = if r.resumed { "resumed" } else { "trained" };
        println!("{}: {how}, {steps} steps, {:.1} s -> {}", r.block, r.seconds, r.run.display());
    }
    Ok(())
}
