//! `msnerf partition ... --slurm`: a Slurm job-array script for the blocks, `BLOCKS/slurm.sh` (submit it with
//! `sbatch BLOCKS/slurm.sh`). One array task per block (`--array=0-(n-1)`), one GPU each (`--gres`, or none for a
//! CPU-only node). Each task runs
//! `msnerf train` on its block with `--resume` when the block already has a checkpoint, so a requeued or preempted
//! task continues. `--signal=B:TERM@120` asks Slurm to send SIGTERM two minutes before the time limit; `exec` makes
//! msnerf the signalled process, and msnerf saves a checkpoint on SIGTERM before it exits.
//!
//! Host memory per task: the largest block's training images at their stored bit depth (the image cache holds
//! them all when they fit its budget; the planner's rule, [`crate::plan::DatasetShape`]) capped at the cache budget,
//! plus 4 GiB for the process. GPU memory depends on the model and the ray batch: `msnerf plan` reports it per card.

use std::path::Path;

use super::error::ScaleError;
use super::partition::Blocks;
use crate::data::{load_dataset, LoadOptions};

/// Options of the job script.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// `--time` of each task (`HH:MM:SS` or `D-HH:MM:SS`).
    pub time: String,
    /// The image cache's host budget per task, bytes (`msnerf train --host-budget-gib`).
    pub host_budget_bytes: u64,
    pub cpus_per_task: usize,
    /// `--gres` of each task (`gpu:1`, `gpu:a100:1`...); empty: none (a CPU-only node, lavapipe).
    pub gres: String,
    /// The msnerf executable the tasks run.
    pub exe: std::path::PathBuf,
    /// Arguments appended to every `msnerf train`.
    pub train_args: Vec<String>,
}

/// Quotes a word for bash (single quotes).
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// Checks a Slurm `--time` value (`HH:MM:SS`, `D-HH:MM:SS` and Slurm's shorter forms: digits, `:` and `-`).
pub fn check_time(time: &str) -> Result<(), ScaleError> {
    let ok = time.chars().next().is_some_and(|c| c.is_ascii_digit())
        && time.chars().all(|c| c.is_ascii_digit() || c == ':' || c == '-');
    if ok {
        Ok(())
    } else {
        Err(ScaleError::option("--slurm-time", format!("`{time}` is not HH:MM:SS or D-HH:MM:SS")))
    }
}

/// Writes `dir/slurm.sh` for `blocks`; returns the memory per task it asks for, in GiB.
pub fn write_job_array(dir: &Path, blocks: &Blocks, o: &SlurmOptions) -> Result<u64, ScaleError> {
    write_job_array_into(dir, dir, blocks, o)
}

/// Writes `slurm.sh` into `write_dir`, a blocks folder that will be found at `final_dir` (the staging folder of
/// [`super::partition::partition_with`] before its rename, so the folder appears with its script or not at all):
/// the block datasets are read from `write_dir`, the script names `final_dir`.
pub fn write_job_array_into(
    write_dir: &Path,
    final_dir: &Path,
    blocks: &Blocks,
    o: &SlurmOptions,
) -> Result<u64, ScaleError> {
    check_time(&o.time)?;
    let dir = final_dir;
    let mut largest = 0u64;
    for b in &blocks.blocks {
        let ds = load_dataset(&write_dir.join(&b.name), &LoadOptions::default())?;
        let shape = crate::plan::DatasetShape::from_dataset(&ds);
        largest = largest.max(shape.bytes_per_image * shape.n_train as u64);
    }
    let gib = largest.min(o.host_budget_bytes).div_ceil(1 << 30) + 4;
    let dir_abs = std::path::absolute(dir).map_err(ScaleError::io(dir))?;
    let names: Vec<String> = blocks.blocks.iter().map(|b| quote(&b.name)).collect();
    let extra: Vec<String> = o.train_args.iter().map(|a| quote(a)).collect();
    let budget_gib = o.host_budget_bytes as f64 / (1u64 << 30) as f64;
    let script = format!(
        "#!/bin/bash\n\
# Written by `msnerf partition --slurm`: one array task per block of {dir}.\n\
# GPU memory per task: see `msnerf plan` for the model and ray batch given below.\n\
#SBATCH --job-name=msnerf-blocks\n\
#SBATCH --array=0-{last}\n\
{gres}\
#SBATCH --cpus-per-task={cpus}\n\
#SBATCH --mem={gib}G\n\
#SBATCH --time={time}\n\
#SBATCH --requeue\n\
#SBATCH --open-mode=append\n\
#SBATCH --signal=B:TERM@120\n\
#SBATCH --output={dir}/slurm-%A_%a.log\n\
set -euo pipefail\n\
BLOCKS=({names})\n\
B=\"${{BLOCKS[$SLURM_ARRAY_TASK_ID]}}\"\n\
DIR={qdir}\n\
RESUME=()\n\
if [ -f \"$DIR/$B/run/checkpoints/latest.json\" ]; then RESUME=(--resume); fi\n\
exec {exe} train --data \"$DIR/$B\" --out \"$DIR/$B/run\" \"${{RESUME[@]}}\" --quiet --host-budget-gib {budget_gib} {extra}\n",
        dir = dir_abs.display(),
        qdir = quote(&dir_abs.display().to_string()),
        last = blocks.blocks.len().saturating_sub(1),
        cpus = o.cpus_per_task.max(1),
        gres = if o.gres.is_empty() { String::new() } else { format!("#SBATCH --gres={}\n", o.gres) },
        time = o.time,
        names = names.join(" "),
        exe = quote(&o.exe.display().to_string()),
        extra = extra.join(" "),
    );
    let p = write_dir.join("slurm.sh");
    crate::util::atomic::write_bytes(&p, script.as_bytes())
        .map_err(|e| ScaleError::Output { path: p.clone(), reason: e.to_string() })?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).map_err(ScaleError::io(&p))?;
    }
    Ok(gib)
}
