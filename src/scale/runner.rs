//! `msnerf train-blocks BLOCKS [--parallel N] [--devices LIST] [-- TRAIN ARGS...]` (issue 23): trains every block of a
//! `msnerf partition` folder on one machine, the local counterpart of the Slurm job array. Each block runs in its own
//! `msnerf train` process (`--data BLOCKS/<block> --out BLOCKS/<block>/run`, the given train arguments after it), so
//! a failing block neither stops nor corrupts the others, as one array task would not. A block whose run already
//! has a checkpoint resumes from it (`--resume`): rerunning the command after an interruption continues every
//! block. Up to `parallel` blocks run at once; `devices` are handed out round robin as `MSNERF_DEVICE` (one GPU per
//! block on a multi-GPU machine). Each process's output goes to `BLOCKS/<block>/train.log`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use super::error::ScaleError;
use super::partition::Blocks;

/// Options of [`train_blocks`].
#[derive(Debug, Clone)]
pub struct TrainBlocksOptions {
    /// The `msnerf` executable that trains (normally this one).
    pub exe: PathBuf,
    pub parallel: usize,
    /// Vulkan devices (`msnerf devices` index or name) handed out round robin; empty: the default device.
    pub devices: Vec<String>,
    /// Arguments appended to every `msnerf train` (model, steps, time budget...).
    pub train_args: Vec<String>,
}

/// What one block's training did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BlockRun {
    pub block: String,
    pub run: PathBuf,
    pub resumed: bool,
    /// Steps the run has completed (its summary), when it finished.
    pub steps: Option<u64>,
    pub seconds: f64,
}

/// Reads `BLOCKS/blocks.json`.
pub fn read_blocks(dir: &Path) -> Result<Blocks, ScaleError> {
    let p = dir.join(super::BLOCKS_FILE);
    let text = std::fs::read_to_string(&p).map_err(|e| ScaleError::Dataset {
        path: p.clone(),
        reason: format!("{e} (is this a folder written by `msnerf partition`?)"),
    })?;
    let b: Blocks = serde_json::from_str(&text)
        .map_err(|e| ScaleError::Dataset { path: p.clone(), reason: format!("invalid blocks.json: {e}") })?;
    // Every cell of the grid holds exactly one block: the merges index blocks by grid cell.
    let [nx, ny] = b.grid;
    let mut seen = vec![false; nx.saturating_mul(ny)];
    for blk in &b.blocks {
        let [ix, iy] = blk.index;
        let cell = (ix < nx && iy < ny).then(|| iy * nx + ix);
        match cell {
            Some(c) if !seen[c] => seen[c] = true,
            _ => {
                return Err(ScaleError::Dataset {
                    path: p,
                    reason: format!(
                        "block {}: index {:?} is outside the {nx}x{ny} grid or taken twice",
                        blk.name, blk.index
                    ),
                })
            }
        }
    }
    if seen.is_empty() || seen.contains(&false) {
        return Err(ScaleError::Dataset {
            path: p,
            reason: format!("the {nx}x{ny} grid has {} blocks: every cell needs one", b.blocks.len()),
        });
    }
    Ok(b)
}

/// Trains every block of `dir`; returns the runs in block order, or an error naming every block that failed.
pub fn train_blocks(dir: &Path, o: &TrainBlocksOptions) -> Result<Vec<BlockRun>, ScaleError> {
    let blocks = read_blocks(dir)?;
    if o.parallel == 0 {
        return Err(ScaleError::option("--parallel", "must be at least 1"));
    }
    for b in &blocks.blocks {
        let t = dir.join(&b.name).join("transforms.json");
        if !t.is_file() {
            return Err(ScaleError::Block { block: b.name.clone(), reason: format!("{} is missing", t.display()) });
        }
    }
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<BlockRun, String>>>> = Mutex::new(vec![None; blocks.blocks.len()]);
    std::thread::scope(|s| {
        for worker in 0..o.parallel.min(blocks.blocks.len()) {
            let (next, results, blocks) = (&next, &results, &blocks);
            s.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(b) = blocks.blocks.get(i) else { break };
                let device = (!o.devices.is_empty()).then(|| o.devices[worker % o.devices.len()].clone());
                let r = run_block(dir, &b.name, device.as_deref(), o);
                results.lock().expect("no panics while held")[i] = Some(r);
            });
        }
    });
    let results = results.into_inner().expect("threads joined");
    let mut runs = Vec::new();
    let mut failed = Vec::new();
    for (b, r) in blocks.blocks.iter().zip(results) {
        match r.expect("every block was run") {
            Ok(run) => runs.push(run),
            Err(e) => failed.push(format!("{}: {e}", b.name)),
        }
    }
    if !failed.is_empty() {
        return Err(ScaleError::Block {
            block: failed.iter().map(|f| f.split(':').next().unwrap_or("")).collect::<Vec<_>>().join(", "),
            reason: format!("training failed (the others finished; rerun to resume):\n  {}", failed.join("\n  ")),
        });
    }
    Ok(runs)
}

fn run_block(dir: &Path, name: &str, device: Option<&str>, o: &TrainBlocksOptions) -> Result<BlockRun, String> {
    let t0 = std::time::Instant::now();
    let data = dir.join(name);
    let run = data.join("run");
    let resumed = run.join("checkpoints/latest.json").is_file();
    let log_path = data.join("train.log");
    // Appended, so a resumed block keeps the log of its earlier runs (as the Slurm script's --open-mode=append).
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|e| format!("{}: {e}", log_path.display()))?;
    let err_log = log.try_clone().map_err(|e| format!("{}: {e}", log_path.display()))?;
    let mut cmd = std::process::Command::new(&o.exe);
    cmd.arg("train").arg("--data").arg(&data).arg("--out").arg(&run).arg("--quiet");
    if resumed {
        cmd.arg("--resume");
    }
    cmd.args(&o.train_args).stdout(log).stderr(err_log);
    if let Some(d) = device {
        cmd.env("MSNERF_DEVICE", d);
    }
    let status = cmd.status().map_err(|e| format!("starting {}: {e}", o.exe.display()))?;
    if !status.success() {
        let tail = std::fs::read_to_string(&log_path).unwrap_or_default();
        let last: Vec<&str> = tail.lines().rev().take(3).collect();
        return Err(format!(
            "msnerf train exited with {status}; {}: {}",
            log_path.display(),
            last.into_iter().rev().collect::<Vec<_>>().join(" | ")
        ));
    }
    let steps = std::fs::read_to_string(run.join("summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v["steps"].as_u64());
    Ok(BlockRun { block: name.to_string(), run, resumed, steps, seconds: t0.elapsed().as_secs_f64() })
}
