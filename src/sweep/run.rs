//! Running a sweep: one training run per cell in `OUT/cells/<id>/` (the trainer's own run folder), trained in
//! segments that end at the grid's wall-clock points (`--time-budget` then `--resume`), with the held-out views
//! rendered and scored per band after each segment. The training clock only counts training, so evaluation never
//! eats into a cell's budget. Resumable: a cell whose `result.json` exists is not redone; a cell without one (the
//! sweep stopped inside it) is started again from scratch.

use super::error::SweepError;
use super::grid::{show_value, Cell, Grid};
use super::result::{BandScore, CellResult, KernelShare, TimePoint};
use crate::data::Split;
use crate::gpu::{Context, KernelTime};
use crate::nerf::run::LoadedRun;
use crate::nerf::trainer::{load_run_dataset, train, TrainOptions};
use crate::util::atomic;
use std::path::{Path, PathBuf};

/// What a sweep needs besides the grid.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    pub data: PathBuf,
    pub out: PathBuf,
    /// Host bytes for the training-image cache of each cell.
    pub host_budget_bytes: u64,
    pub progress: bool,
}

/// What became of each cell in this call.
#[derive(Clone, Debug, Default)]
pub struct SweepOutcome {
    /// Every finished cell, in grid order (done before and done now).
    pub results: Vec<CellResult>,
    /// Ids of the cells found done and skipped.
    pub skipped: Vec<String>,
    /// Ids of the cells trained in this call.
    pub trained: Vec<String>,
    /// (cell id, error) of cells that failed; they are retried on the next run.
    pub failed: Vec<(String, String)>,
}

/// FNV-1a, 64 bit: a stable hash for cell ids (std's hasher is not stable across releases).
fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// A cell's folder name: a readable label and a hash of everything that makes its numbers what they are (base
/// model, settings, budget, evaluation points), so an edited grid reuses exactly the cells that did not change.
pub fn cell_id(grid: &Grid, cell: &Cell) -> String {
    let mut label: String = cell
        .values
        .iter()
        .map(|(k, v)| {
            let short = k.rsplit('.').next().unwrap_or(k);
            let v = show_value(v);
            let v = v.rsplit('/').next().unwrap_or(&v).trim_end_matches(".yaml").to_string();
            format!("{short}-{v}")
        })
        .collect::<Vec<_>>()
        .join("_");
    label.retain(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '+' | '.'));
    label.truncate(60);
    if label.is_empty() {
        label = "base".into();
    }
    let key = format!(
        "{}|{}|{:?}|{:?}|{:?}|{}|{}",
        grid.model,
        cell.describe(),
        grid.budget.time_s,
        grid.budget.steps,
        grid.eval_at_s,
        grid.eval_views,
        grid.eval_pixels
    );
    format!("{label}-{:08x}", fnv1a(&key) as u32)
}

/// The folder of a cell.
pub fn cell_dir(out: &Path, id: &str) -> PathBuf {
    out.join("cells").join(id)
}

/// A finished cell's result, if it is there and was measured under this grid's budget.
pub fn done_result(grid: &Grid, out: &Path, id: &str) -> Option<CellResult> {
    let r = CellResult::read(&cell_dir(out, id).join("result.json")).ok()?;
    (r.id == id && r.budget_time_s == grid.budget.time_s && r.budget_steps == grid.budget.steps).then_some(r)
}

/// Runs every cell that is not done yet, in grid order. A failing cell is recorded (`error.txt` in its folder) and
/// the others still run; the caller decides how to exit.
pub fn run_sweep(ctx: &Context, grid: &Grid, opts: &SweepOptions) -> Result<SweepOutcome, SweepError> {
    // Band subsets are checked against the dataset before any cell trains.
    for c in &grid.cells {
        let cc = grid.resolve(c)?;
        if let Some(b) = &cc.bands {
            load_run_dataset(&opts.data, Some(b), &cc.model.sampling).map_err(|e| SweepError::Cell {
                index: c.index,
                describe: c.describe(),
                reason: e.to_string(),
            })?;
        }
    }
    std::fs::create_dir_all(opts.out.join("cells")).map_err(|e| SweepError::file(&opts.out, e))?;
    let mut outcome = SweepOutcome::default();
    let n = grid.cells.len();
    for cell in &grid.cells {
        let id = cell_id(grid, cell);
        if let Some(r) = done_result(grid, &opts.out, &id) {
            if opts.progress {
                eprintln!("[{}/{n}] {id}: done before, skipped", cell.index + 1);
            }
            outcome.skipped.push(id);
            outcome.results.push(r);
            continue;
        }
        if opts.progress {
            eprintln!("[{}/{n}] {id}: {}", cell.index + 1, cell.describe());
        }
        match run_cell(ctx, grid, cell, &id, opts) {
            Ok(r) => {
                if opts.progress {
                    let f = r.final_point();
                    eprintln!(
                        "      {} steps in {:.0} s ({:.0} ms/step); held-out PSNR {} dB",
                        r.steps,
                        r.elapsed_s,
                        r.mean_step_ms,
                        f.map(|p| format!("{:.2}", p.psnr)).unwrap_or_else(|| "n/a".into())
                    );
                }
                outcome.trained.push(id);
                outcome.results.push(r);
            }
            Err(e) => {
                let msg = format!("cell {} ({}): {e}", cell.index, cell.describe());
                eprintln!("      failed: {msg}");
                let _ = atomic::write_bytes(&cell_dir(&opts.out, &id).join("error.txt"), msg.as_bytes());
                outcome.failed.push((id, msg));
            }
        }
    }
    Ok(outcome)
}

/// The training segments of a cell: each eval point, then the end of the budget (`None`: no time limit, the step
/// budget ends it).
fn segment_ends(grid: &Grid) -> Vec<Option<f64>> {
    let mut ends: Vec<Option<f64>> = grid.eval_at_s.iter().map(|&t| Some(t)).collect();
    match grid.budget.time_s {
        Some(t) if grid.eval_at_s.last().is_some_and(|&l| (l - t).abs() < 1e-9) => {}
        t => ends.push(t),
    }
    ends
}

/// Trains and evaluates one cell from scratch, then writes its `result.json` (last, atomically).
pub fn run_cell(
    ctx: &Context,
    grid: &Grid,
    cell: &Cell,
    id: &str,
    opts: &SweepOptions,
) -> Result<CellResult, SweepError> {
    let cc = grid.resolve(cell)?;
    let dir = cell_dir(&opts.out, id);
    if dir.exists() {
        // An unfinished cell: its partial timings would mix with new ones, so it starts again.
        std::fs::remove_dir_all(&dir).map_err(|e| SweepError::file(&dir, e))?;
    }
    std::fs::create_dir_all(&dir).map_err(|e| SweepError::file(&dir, e))?;
    let mut model = cc.model.clone();
    model.trainer.max_steps = grid.budget.steps.unwrap_or(u64::MAX / 2);
    // The trainer's own pixel check runs at step 1 and where each segment stops, not periodically.
    model.trainer.steps_per_eval = u64::MAX / 2;
    model.trainer.steps_per_save = u64::MAX / 2;
    let mut points = Vec::new();
    let (mut steps_done, mut step_ms_sum, mut gpu_ms_sum) = (0u64, 0.0f64, 0.0f64);
    let mut kernels: Vec<KernelTime> = Vec::new();
    let (mut peak_gpu, mut peak_cache) = (0u64, 0u64);
    let mut trainer_best = None;
    let mut stopped = String::new();
    let mut elapsed = 0.0;
    let mut steps = 0;
    let mut band_names = Vec::new();
    let mut parameters = 0;
    for (k, end) in segment_ends(grid).into_iter().enumerate() {
        let t = TrainOptions {
            data: opts.data.clone(),
            model: model.clone(),
            out: dir.clone(),
            resume: k > 0,
            time_budget_s: end,
            host_budget_bytes: opts.host_budget_bytes,
            resample_every: 500,
            eval_pixels: grid.eval_pixels,
            progress: false,
            stop: None,
            bands: cc.bands.clone(),
        };
        let s = train(ctx, &t).map_err(|e| SweepError::Run { what: "training".into(), err: Box::new(e) })?;
        let seg_steps = s.steps - steps;
        steps = s.steps;
        elapsed = s.elapsed_s;
        steps_done += seg_steps;
        step_ms_sum += s.mean_step_ms * seg_steps as f64;
        gpu_ms_sum += s.gpu_ms_per_step * seg_steps as f64;
        for kt in &s.kernels {
            let w = seg_steps as f64;
            match kernels.iter_mut().find(|x| x.name == kt.name) {
                Some(x) => {
                    x.count += kt.count;
                    x.total_ms += kt.total_ms * w;
                }
                None => kernels.push(KernelTime { name: kt.name.clone(), count: kt.count, total_ms: kt.total_ms * w }),
            }
        }
        peak_gpu = peak_gpu.max(s.peak_gpu_bytes);
        peak_cache = peak_cache.max(s.peak_cache_bytes);
        trainer_best = s.best_eval_psnr.or(trainer_best);
        let by_steps = grid.budget.steps.is_some_and(|m| s.steps >= m);
        stopped = if by_steps {
            format!("step budget of {} steps", s.steps)
        } else {
            s.stopped_early.clone().unwrap_or_else(|| "end of budget".into())
        };
        let (point, names, n_params) =
            evaluate_point(ctx, &dir, grid.eval_views, end.unwrap_or(elapsed), elapsed, steps)?;
        band_names = names;
        parameters = n_params;
        points.push(point);
        if by_steps {
            break;
        }
    }
    let n = steps_done.max(1) as f64;
    let mut kernels: Vec<KernelShare> = kernels
        .into_iter()
        .map(|k| KernelShare { name: k.name, calls_per_step: k.count as f64 / n, ms_per_step: k.total_ms / n })
        .collect();
    kernels.sort_by(|a, b| b.ms_per_step.total_cmp(&a.ms_per_step).then(a.name.cmp(&b.name)));
    let result = CellResult {
        id: id.to_string(),
        index: cell.index,
        label: cell.describe(),
        values: cell.values.iter().map(|(k, v)| (k.clone(), show_value(v))).collect(),
        model: cc.model.name.clone(),
        band_names,
        budget_time_s: grid.budget.time_s,
        budget_steps: grid.budget.steps,
        steps,
        elapsed_s: elapsed,
        mean_step_ms: step_ms_sum / n,
        gpu_ms_per_step: gpu_ms_sum / n,
        kernels,
        peak_gpu_bytes: peak_gpu,
        peak_cache_bytes: peak_cache,
        parameters,
        points,
        trainer_best_eval_psnr: trainer_best,
        stopped,
    };
    result.write(&dir.join("result.json"))?;
    Ok(result)
}

/// Renders the held-out views of a cell's latest checkpoint and scores them per band; also returns the band names
/// and the parameter count.
fn evaluate_point(
    ctx: &Context,
    dir: &Path,
    views: usize,
    target_s: f64,
    elapsed_s: f64,
    step: u64,
) -> Result<(TimePoint, Vec<String>, u64), SweepError> {
    let mut run = LoadedRun::load(ctx, dir)
        .map_err(|e| SweepError::Run { what: "loading the checkpoint".into(), err: Box::new(e) })?;
    let has_depth = run.ds.split_indices(Split::Eval).iter().all(|&f| run.ds.frames[f].depth.is_some());
    let rep = crate::nerf::evaluate::evaluate(&mut run, Split::Eval, Some(views), None, has_depth)
        .map_err(|e| SweepError::Stage { what: "evaluating".into(), reason: e.to_string() })?;
    let bands =
        rep.bands.iter().map(|b| BandScore { name: b.name.clone(), psnr: b.psnr, ssim: b.ssim }).collect::<Vec<_>>();
    let names = bands.iter().map(|b| b.name.clone()).collect();
    let geometry = geometry_score(&mut run, rep.depth.as_ref())?;
    let point =
        TimePoint { target_s, elapsed_s, step, psnr: rep.results.psnr, ssim: rep.results.ssim, bands, geometry };
    Ok((point, names, run.pipe.model.n_params() as u64))
}

/// Rays the sweep's point-cloud export renders per evaluation point.
const SWEEP_EXPORT_RAYS: usize = 50_000;
/// Distance threshold of the sweep's cloud F-score (metres).
const SWEEP_CLOUD_THRESHOLD_M: f64 = 0.25;

/// Depth statistics from the evaluation and, when the dataset folder holds the simulator's `ground_truth.ply`, the
/// default export (careful, and photometrically refined since 2026-11-27) compared with it; None when neither is
/// available.
fn geometry_score(
    run: &mut LoadedRun,
    depth: Option<&crate::output::metrics::depth::DepthReport>,
) -> Result<Option<super::result::GeometryScore>, SweepError> {
    use crate::output::compare::{compare_clouds_with, AccuracyOptions, CompareOptions};
    let truth = run.ds.root.join("ground_truth.ply");
    if depth.is_none() && !truth.is_file() {
        return Ok(None);
    }
    let fin = |v: f64| v.is_finite().then_some(v);
    let mut g = super::result::GeometryScore::default();
    if let Some(d) = depth {
        let o = &d.overall;
        g.depth_median_abs_m = fin(o.median_abs_error);
        g.depth_bias_m = fin(o.median_bias);
        g.depth_bias_footprints = fin(o.median_bias_footprints);
        g.depth_within_half_footprint = fin(o.within_half_footprint);
        g.depth_within_one_footprint = fin(o.within_one_footprint);
        g.median_footprint_m = fin(o.median_footprint);
    }
    if truth.is_file() {
        let reference = crate::output::pointcloud::read_ply(&truth).map_err(|e| SweepError::file(&truth, e))?;
        let opts = crate::nerf::export::ExportOptions { rays: SWEEP_EXPORT_RAYS, ..Default::default() };
        let cloud = crate::nerf::export::export_points(run, &opts)
            .map_err(|e| SweepError::Run { what: "exporting the cloud".into(), err: Box::new(e) })?;
        if !cloud.is_empty() {
            let c = CompareOptions { threshold: SWEEP_CLOUD_THRESHOLD_M, ..Default::default() };
            let r = compare_clouds_with(&cloud, &reference, &c, &AccuracyOptions::default()).map_err(|e| {
                SweepError::Stage { what: "comparing the exported cloud".into(), reason: e.to_string() }
            })?;
            g.cloud_accuracy_median_m = fin(r.accuracy.median);
            g.cloud_completeness_median_m = fin(r.completeness.median);
            g.cloud_f_score = fin(r.f_score);
            g.cloud_rmse_planar_m = fin(r.position.rmse_planar);
            g.cloud_rmse_vertical_m = fin(r.position.rmse_elevation);
            g.cloud_median_signed_dz_m = fin(r.position.median_signed_dz);
            g.standard_pass = Some(r.standard.pass);
        }
        g.cloud_points = Some(cloud.len());
        g.cloud_threshold_m = Some(SWEEP_CLOUD_THRESHOLD_M);
    }
    Ok(Some(g))
}
