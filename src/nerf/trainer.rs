//! `msnerf train`: the training loop around [`Pipeline`]. Loads and normalises the dataset, keeps training images in
//! the host cache (within a byte budget), samples ray batches, steps the pipeline, evaluates held-out PSNR every
//! `steps_per_eval` steps on a fixed set of held-out pixels, and keeps a run folder:
//!
//! ```text
//! RUN/config.yaml                    merged model config (after CLI overrides)
//! RUN/dataparser_transforms.json     pose normalisation (nerfstudio's format), to map outputs back to the world
//! RUN/dataset.json                   dataset path, bands, splits
//! RUN/checkpoints/latest.msnp        parameters + Adam state (atomic), and latest.json (trainer state)
//! RUN/metrics.jsonl                  one JSON object per logged step and per evaluation
//! RUN/camera_poses.json              refined camera poses (with pose refinement on; `super::camera_poses`)
//! ```
//! Ctrl-C or SIGTERM (a Slurm preemption or time limit) saves a checkpoint and stops; `--resume` continues from the
//! latest one; `--time-budget` stops in time.

use super::background_guard::{band_p99_max, constant_psnr, BackgroundGuard, NOTHING_LEARNT_DB, SMALL_VALUES};
use super::config::{LrSchedule, ModelConfig};
use super::error::{NerfError, NerfResult};
use super::model::Model;
use super::pipeline::{Batch, Pipeline, StepStats};
use super::rays::GpuCamera;
use super::rig_rays::RigRays;
use super::schedule::ProposalSchedule;
use crate::data::{cache, load_dataset, Dataset, LoadOptions, Split};
use crate::gpu::{Context, KernelTime, TimingReport};
use crate::util::atomic;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub data: PathBuf,
    pub model: ModelConfig,
    pub out: PathBuf,
    pub resume: bool,
    pub time_budget_s: Option<f64>,
    /// Host bytes the image cache may use.
    pub host_budget_bytes: u64,
    /// Resample the resident images every this many steps (paper §6.1).
    pub resample_every: u64,
    /// Held-out pixels evaluated every `steps_per_eval` steps.
    pub eval_pixels: usize,
    pub progress: bool,
    pub stop: Option<Arc<AtomicBool>>,
    /// Train on these bands of the dataset only (indices into its band list, in order); `None`: all of them.
    pub bands: Option<Vec<usize>>,
}

/// Trainer state saved next to each checkpoint.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainerState {
    pub step: u64,
    pub schedule: ProposalSchedule,
    pub best_eval_psnr: Option<f64>,
    pub elapsed_s: f64,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct TrainSummary {
    pub steps: u64,
    pub final_loss: f64,
    pub final_train_psnr: f64,
    pub first_eval_psnr: Option<f64>,
    pub best_eval_psnr: Option<f64>,
    /// The step at which `best_eval_psnr` was reached (in this call; `None` when it came from before a resume).
    pub best_eval_step: Option<u64>,
    pub eval_history: Vec<(u64, f64)>,
    pub elapsed_s: f64,
    pub rays_per_s: f64,
    /// Mean host time of one training step in this call (`Pipeline::train_step`, excluding batch sampling).
    pub mean_step_ms: f64,
    /// Mean GPU time of one step and its per-kernel breakdown (ms per step, largest first), from the timestamps.
    pub gpu_ms_per_step: f64,
    pub kernels: Vec<KernelTime>,
    pub stopped_early: Option<String>,
    pub peak_gpu_bytes: u64,
    pub peak_cache_bytes: u64,
    pub run_dir: PathBuf,
    /// The device, the `MSNERF_*` switches that were set (`util::env`) and the field MLP's kernel tiling, so the
    /// numbers above can be traced to what produced them.
    pub device: String,
    pub environment: Vec<String>,
    pub mlp_tiling: String,
    /// What depth supervision did in this run (`loss.depth` resolved against the dataset).
    pub depth_supervision: String,
    /// Named warnings of the run: a field that turned transparent and was re-warmed, a run that learnt nothing
    /// ([`NOTHING_LEARNT`]).
    pub notes: Vec<String>,
}

/// The start of the note of a run whose held-out PSNR stayed near a constant colour's.
pub const NOTHING_LEARNT: &str = "nothing learnt";

/// Consecutive NaN/Inf-poisoned steps after which training stops.
pub const MAX_POISONED_STEPS: u32 = 5;

/// The normalised camera table (GPU layout): every frame's camera, then, for a dataset with `rig_cameras`, every
/// frame's band cameras ([`RigRays::table`]).
pub fn camera_table(ds: &Dataset) -> Vec<GpuCamera> {
    let t = ds.pose_transform();
    let mut table: Vec<GpuCamera> = ds
        .frames
        .iter()
        .map(|f| {
            let m = t.pose_to_normalized(&f.c2w);
            let c2w: [[f32; 4]; 3] = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| m[r][c] as f32));
            GpuCamera::new(&f.camera, &c2w)
        })
        .collect();
    table.extend(RigRays::table(ds));
    table
}

/// Fixed held-out pixels (camera, row, col) with their values and ray weights, drawn from the eval split; with
/// `rig_cameras`, rig rays (one band each, NaN for the others: [`RigRays`]).
pub struct EvalSet {
    pub pixels: Vec<u32>,
    pub targets: Vec<f32>,
}

pub fn eval_set(ds: &Dataset, n: usize, seed: u64) -> NerfResult<EvalSet> {
    let frames = ds.split_indices(Split::Eval);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_e7a1);
    let b = ds.n_bands();
    let mut set = EvalSet { pixels: Vec::new(), targets: Vec::new() };
    if frames.is_empty() || n == 0 {
        return Ok(set);
    }
    let per = n.div_ceil(frames.len());
    let rig = RigRays::new(ds);
    let mut batch = Batch::default();
    for &fi in &frames {
        let img = ds.read_frame(fi)?;
        let mut px = crate::data::PixelBatch { bands: b, values: vec![0.0f32; per * b], ..Default::default() };
        for k in 0..per {
            let (row, col) = (rng.random_range(0..ds.height), rng.random_range(0..ds.width));
            img.pixel_into(row, col, &mut px.values[k * b..(k + 1) * b]);
            px.image.push(fi as u32);
            px.row.push(row);
            px.col.push(col);
            px.mask.push(img.mask_at(row, col));
        }
        push_pixels(&mut batch, &px, rig.as_ref(), false, None);
    }
    set.pixels = batch.pixels;
    set.targets = batch.targets;
    Ok(set)
}

/// Appends sampled pixels to a batch: plain rays through the frame camera, or rig rays ([`RigRays::push`];
/// `frame_rays` for pixels drawn for their depth targets); `depth` gives a ray's depth target.
fn push_pixels(
    batch: &mut Batch,
    px: &crate::data::PixelBatch,
    rig: Option<&RigRays>,
    frame_rays: bool,
    depth: Option<&super::depth_targets::DepthTargets>,
) {
    let mut column = |f: usize, row: u32, col: u32| depth.map_or([0.0, 1.0], |d| d.column(f, row, col));
    if let Some(rig) = rig {
        rig.push(batch, px, frame_rays, depth.map(|_| &mut column as &mut dyn FnMut(usize, u32, u32) -> [f32; 2]));
        return;
    }
    let bands = px.bands;
    for i in 0..px.image.len() {
        batch.pixels.extend([px.image[i], px.row[i], px.col[i]]);
        batch.targets.extend_from_slice(&px.values[i * bands..(i + 1) * bands]);
        batch.targets.push(if px.mask[i] == 0 { 0.0 } else { 1.0 });
        if depth.is_some() {
            batch.depth.extend(column(px.image[i] as usize, px.row[i], px.col[i]));
        }
    }
}

/// Held-out PSNR (data range 1) over the eval set: mean squared error over unmasked pixels and the bands each
/// pixel observed (all of them, but one for rig rays).
pub fn eval_psnr(pipe: &mut Pipeline, set: &EvalSet) -> NerfResult<f64> {
    let out = pipe.render(&set.pixels).map_err(NerfError::gpu("rendering the held-out pixels"))?;
    let b = pipe.model.bands;
    let (mut sq, mut count) = (0.0f64, 0.0f64);
    for i in 0..set.pixels.len() / 3 {
        let w = set.targets[i * (b + 1) + b] as f64;
        for k in 0..b {
            let y = set.targets[i * (b + 1) + k] as f64;
            if !y.is_nan() {
                let e = out.colour[i * b + k] as f64 - y;
                sq += w * e * e;
                count += w;
            }
        }
    }
    Ok(-10.0 * (sq / count.max(1.0)).max(1e-20).log10())
}

fn ckpt_paths(run: &Path) -> (PathBuf, PathBuf) {
    let d = run.join("checkpoints");
    (d.join("latest.msnp"), d.join("latest.json"))
}

fn save_checkpoint(pipe: &Pipeline, run: &Path, state: &TrainerState, ds: &Dataset) -> NerfResult<()> {
    let (p, s) = ckpt_paths(run);
    let dir = p.parent().expect("has parent");
    std::fs::create_dir_all(dir).map_err(|e| NerfError::file(dir, e))?;
    pipe.model.store.save(&p)?;
    write_atomic_str(&s, serde_json::to_string_pretty(state).expect("serialisable").as_bytes())?;
    let store = &pipe.model.store;
    if let Some(slot) = &pipe.model.slots.pose {
        let poses = store.download_slot(store.params(), slot).map_err(NerfError::gpu("reading the refined poses"))?;
        let doc =
            super::camera_poses::camera_poses_json(ds, &ds.pose_transform(), &ds.split_indices(Split::Train), &poses);
        write_atomic_str(&run.join("camera_poses.json"), serde_json::to_string_pretty(&doc).expect("json").as_bytes())?;
    }
    Ok(())
}

/// Adds one step's timestamps to per-kernel totals (kept by name; the dispatch list itself is not kept).
fn add_kernel_times(totals: &mut Vec<KernelTime>, timing: &TimingReport) {
    for k in timing.by_kernel() {
        match totals.iter_mut().find(|t| t.name == k.name) {
            Some(t) => {
                t.count += k.count;
                t.total_ms += k.total_ms;
            }
            None => totals.push(k),
        }
    }
}

/// Loads the dataset a run trains on: `data` with only the bands in `bands` when given, poses normalised and
/// outlying cameras handled as the model's `sampling` section says.
pub fn load_run_dataset(
    data: &Path,
    bands: Option<&[usize]>,
    sampling: &crate::nerf::config::SamplingConfig,
) -> NerfResult<Dataset> {
    let opts = LoadOptions {
        normalization: sampling.pose_normalization,
        drop_outliers: sampling.drop_outlier_cameras,
        ..Default::default()
    };
    let mut ds = load_dataset(data, &opts)?;
    ds.check_distinct_centres()?;
    if !sampling.rig_cameras {
        ds.rig = None;
    }
    if let Some(b) = bands {
        ds.select_bands(b)?;
    }
    Ok(ds)
}

/// Resolves `loss.depth` with `when: available` against the dataset: kept when the dataset has its source, dropped
/// (the run trains on the images alone) otherwise. Returns what was decided, for the log and the summary.
pub fn resolve_depth_supervision(cfg: &mut crate::nerf::config::ModelConfig, ds: &Dataset) -> String {
    use crate::nerf::config::{DepthSource, DepthWhen};
    let Some(d) = cfg.loss.depth else { return "off".into() };
    let (has, what) = match d.source {
        DepthSource::SparsePoints => (ds.sparse_points_path.is_some(), "sparse points"),
        DepthSource::DepthMaps => (ds.frames.iter().any(|f| f.depth.is_some()), "depth maps"),
    };
    match (d.when, has) {
        (DepthWhen::Available, false) => {
            cfg.loss.depth = None;
            format!("off: the dataset has no {what} (images only; `msnerf sfm` or `import poses` bring sparse points)")
        }
        _ => format!("{:?} from the dataset's {what} (sigma {} world units, weight {})", d.loss, d.sigma, d.mult),
    }
}

/// Runs training; returns the summary. Errors are messages that name the file, key or step.
pub fn train(ctx: &Context, opts: &TrainOptions) -> NerfResult<TrainSummary> {
    let mut model_cfg = opts.model.clone();
    let mut ds = load_run_dataset(&opts.data, opts.bands.as_deref(), &model_cfg.sampling)?;
    let depth_note = resolve_depth_supervision(&mut model_cfg, &ds);
    log::info!("depth supervision: {depth_note}");
    let cfg = &model_cfg;
    ds.options.alpha_background = cfg.rendering.alpha_background(true);
    let bands = ds.n_bands();
    cfg.band_weights(bands)?;
    let train_frames = ds.split_indices(Split::Train);
    if train_frames.is_empty() {
        return Err(NerfError::key(&ds.transforms_path, "frames", "the train split is empty"));
    }
    if cfg.camera_optimizer.enabled() && ds.aerial_layout() {
        // Measured on the campus flight (docs/geometry.md, "On an NVIDIA H100"): with exact poses SO3xR3 moved the
        // cameras by ~3 pixels and cost 8.8 dB held out and most of the geometry.
        log::warn!(
            "{}: pose refinement (camera_optimizer {:?}) is on for an aerial flight; on bundle-adjusted or RTK poses it \
             degrades held-out images and geometry (docs/geometry.md): set `camera_optimizer: {{mode: \"off\"}}` \
             unless the poses are rough",
            ds.transforms_path.display(),
            cfg.camera_optimizer.mode
        );
    }
    let run = &opts.out;
    let model = Model::new(ctx, cfg, bands, ds.frames.len())?;
    let mut pipe = Pipeline::new(ctx, model, &camera_table(&ds)).map_err(NerfError::gpu("building the pipeline"))?;
    pipe.n_train_cameras = train_frames.len();
    pipe.appearance_rows = Some(train_frames.clone());
    let mut state =
        TrainerState { step: 0, schedule: ProposalSchedule::default(), best_eval_psnr: None, elapsed_s: 0.0 };
    if opts.resume {
        // The run resumes on the dataset it trained on, or not at all.
        let info_path = run.join("dataset.json");
        if let Ok(text) = std::fs::read_to_string(&info_path) {
            let info: serde_json::Value = serde_json::from_str(&text).map_err(|e| NerfError::file(&info_path, e))?;
            super::run::check_run_dataset(&info_path, &info, &ds)?;
        }
        let (p, s) = ckpt_paths(run);
        let text = std::fs::read_to_string(&s).map_err(|e| NerfError::file(&s, format!("{e} (nothing to resume)")))?;
        state = serde_json::from_str(&text).map_err(|e| NerfError::file(&s, e))?;
        pipe.model.store.load(&p)?;
        pipe.step = state.step;
        pipe.schedule = state.schedule;
    }
    let mut cache = cache::ImageCache::new(
        &ds,
        train_frames.clone(),
        cache::CacheConfig {
            budget_bytes: opts.host_budget_bytes,
            resample_every: opts.resample_every,
            seed: cfg.trainer.seed ^ state.step,
        },
    )?;
    let eval = eval_set(&ds, opts.eval_pixels, cfg.trainer.seed)?;
    let rig = RigRays::new(&ds);
    let near_far = (cfg.sampling.near as f64, cfg.sampling.far as f64);
    let depth = match &cfg.loss.depth {
        Some(d) => Some(super::depth_targets::DepthTargets::build(&ds, &train_frames, d, near_far)?),
        None => None,
    };
    // The run folder is written only once everything above has been checked: a refused run leaves none behind.
    std::fs::create_dir_all(run).map_err(|e| NerfError::file(run, e))?;
    write_atomic_str(
        &run.join("config.yaml"),
        serde_yaml::to_string(cfg).expect("a model config serialises").as_bytes(),
    )?;
    write_atomic_str(&run.join("dataparser_transforms.json"), ds.pose_transform().to_json().as_bytes())?;
    let ds_info = serde_json::json!({
        "data": opts.data, "bands": ds.bands, "band_indices": opts.bands, "width": ds.width, "height": ds.height,
        "train_frames": train_frames, "eval_frames": ds.split_indices(Split::Eval),
        "dropped_outliers": ds.dropped_outliers,
    });
    write_atomic_str(&run.join("dataset.json"), serde_json::to_string_pretty(&ds_info).expect("json").as_bytes())?;

    let mut rng = ChaCha8Rng::seed_from_u64(cfg.trainer.seed.wrapping_add(state.step.wrapping_mul(0x9e37_79b9)));
    let metrics_path = run.join("metrics.jsonl");
    let metrics = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&metrics_path)
        .map_err(|e| NerfError::file(&metrics_path, e))?;
    let max_steps = cfg.trainer.max_steps;
    let bar = opts.progress.then(|| {
        let b = indicatif::ProgressBar::new(max_steps);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} step {pos}/{len} {msg} ETA {eta}")
                .expect("valid template"),
        );
        b.set_position(state.step);
        b
    });
    // Pipeline compilation (lavapipe: at each kernel's first dispatch) happens here, before the clock starts.
    pipe.warm_up().map_err(NerfError::gpu("kernel warm-up"))?;
    pipe.profile_every = cfg.trainer.profile_every;
    ctx.with_ledger(|l| l.reset_peaks());
    let start = Instant::now();
    let elapsed0 = state.elapsed_s;
    let mut summary = TrainSummary {
        run_dir: run.clone(),
        best_eval_psnr: state.best_eval_psnr,
        depth_supervision: depth_note.clone(),
        ..Default::default()
    };
    let mut steps =
        StepLog::new(metrics, metrics_path, bar, run.join("checkpoints"), (cfg.trainer.rays_per_batch, max_steps));
    // A resumed run past its warm-up has nothing left to guard.
    steps.guard = BackgroundGuard::new(&cfg.rendering).filter(|g| state.step < g.switch_at);
    let mut step_ms_total = 0.0f64;
    let r = cfg.trainer.rays_per_batch;
    // Steps submitted; `state.step` counts the completed ones (they differ by the steps in flight).
    let mut submitted = state.step;
    while submitted < max_steps {
        if opts.stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed)) {
            summary.stopped_early = Some("interrupted (SIGINT or SIGTERM)".into());
            break;
        }
        let elapsed = elapsed0 + start.elapsed().as_secs_f64();
        if opts.time_budget_s.is_some_and(|t| elapsed >= t) {
            summary.stopped_early = Some(format!("time budget of {:.0} s reached", opts.time_budget_s.unwrap_or(0.0)));
            break;
        }
        cache.step()?;
        let n_depth = depth.as_ref().map_or(0, |d| d.rays_per_batch(r));
        let mut batches = vec![cache.sample_pixels(&mut rng, r - n_depth)];
        if let Some(d) = depth.as_ref().filter(|_| n_depth > 0) {
            batches.push(d.sample_pixels(&cache, &mut rng, n_depth));
        }
        let mut batch = Batch::default();
        for (k, px) in batches.iter().enumerate() {
            push_pixels(&mut batch, px, rig.as_ref(), k == 1, depth.as_ref());
        }
        if cfg.optimizer.schedule == LrSchedule::Run {
            pipe.model.store.set_run_progress(Some(run_progress(submitted, max_steps, elapsed, opts.time_budget_s)));
        }
        let t0 = Instant::now();
        pipe.submit_step(&batch).map_err(NerfError::gpu(format!("step {submitted}")))?;
        submitted += 1;
        steps.rays_done += batch.rays() as u64;
        let is_last = submitted == max_steps;
        let out_of_time = opts.time_budget_s.is_some_and(|t| elapsed0 + start.elapsed().as_secs_f64() >= t);
        // `out_of_time`: the loop stops before the next step, so the model it leaves is evaluated too and the best
        // held-out PSNR of a time-budgeted run includes where it ended.
        let want_eval = !eval.pixels.is_empty()
            && (submitted % cfg.trainer.steps_per_eval == 0 || is_last || submitted == 1 || out_of_time);
        let want_save = submitted % cfg.trainer.steps_per_save == 0 && !is_last;
        // Evaluations and checkpoints see exactly the steps submitted so far: wait for them first.
        let done = if want_eval || want_save { pipe.flush() } else { pipe.completed() };
        let done = done.map_err(NerfError::gpu(format!("step {}", submitted - 1)))?;
        step_ms_total += t0.elapsed().as_secs_f64() * 1e3;
        steps.take(done, &mut state)?;
        if let Some(end) = steps.rewarm_to.take() {
            pipe.model.cfg.rendering.random_background_steps = end;
        }
        if want_eval {
            let p = eval_psnr(&mut pipe, &eval)?;
            summary.first_eval_psnr.get_or_insert(p);
            summary.eval_history.push((state.step, p));
            if state.best_eval_psnr.is_none_or(|b| p > b) {
                state.best_eval_psnr = Some(p);
                summary.best_eval_step = Some(state.step);
            }
            steps.log(
                serde_json::json!({"step": state.step, "eval_psnr": p, "elapsed_s": elapsed0 + start.elapsed().as_secs_f64()}),
            )?;
        }
        if want_save {
            state.schedule = pipe.schedule;
            state.elapsed_s = elapsed0 + start.elapsed().as_secs_f64();
            save_checkpoint(&pipe, run, &state, &ds)?;
        }
    }
    let t0 = Instant::now();
    let done = pipe.flush().map_err(NerfError::gpu(format!("step {}", submitted.saturating_sub(1))))?;
    step_ms_total += t0.elapsed().as_secs_f64() * 1e3;
    steps.take(done, &mut state)?;
    if steps.completed > 0 && steps.good == 0 {
        let buffer = steps.first_poisoned.take().unwrap_or_default();
        return Err(NerfError::NothingTrained { steps: steps.completed, buffer });
    }
    state.schedule = pipe.schedule;
    if let Some(b) = &steps.bar {
        b.finish_and_clear();
    }
    state.elapsed_s = elapsed0 + start.elapsed().as_secs_f64();
    save_checkpoint(&pipe, run, &state, &ds)?;
    let last = &steps.last;
    summary.steps = state.step;
    summary.final_loss = last.loss;
    summary.final_train_psnr = last.psnr;
    summary.best_eval_psnr = state.best_eval_psnr;
    summary.elapsed_s = state.elapsed_s;
    summary.rays_per_s = steps.rays_done as f64 / start.elapsed().as_secs_f64().max(1e-9);
    summary.peak_gpu_bytes = ctx.with_ledger(|l| l.total_peak());
    summary.peak_cache_bytes = cache.peak_bytes();
    summary.mean_step_ms = step_ms_total / steps.completed.max(1) as f64;
    let profiled = steps.profiled_steps.max(1) as f64;
    summary.gpu_ms_per_step = steps.gpu_ms_total / profiled;
    let mut kernel_totals = std::mem::take(&mut steps.kernel_totals);
    for k in &mut kernel_totals {
        k.total_ms /= profiled;
    }
    kernel_totals.sort_by(|a, b| b.total_ms.total_cmp(&a.total_ms).then(a.name.cmp(&b.name)));
    summary.kernels = kernel_totals;
    summary.device = ctx.caps().summary_line();
    summary.environment = crate::util::env::settings().set_switches();
    summary.mlp_tiling = format!("{:?}", pipe.model.field.mlp.tiling);
    summary.notes = steps.guard.as_ref().map(|g| g.notes.clone()).unwrap_or_default();
    let small = band_p99_max(&eval.targets, bands).filter(|m| *m < SMALL_VALUES);
    if let Some(m) = small {
        let note = format!(
            "the held-out values are small in every band (99th percentile at most {m:.3}): the colour head's sigmoid \
             fits values near 0 slowly (radiance trains several times slower than reflectance of the same scene); \
             import reflectance (`import rig` without `--units radiance`) where the flight allows"
        );
        log::warn!("{note}");
        summary.notes.push(note);
    }
    if let (Some(best), Some(c)) = (summary.best_eval_psnr, constant_psnr(&eval.targets, bands)) {
        if best < c + NOTHING_LEARNT_DB {
            let note = format!(
                "{NOTHING_LEARNT}: the best held-out PSNR, {best:.2} dB, is within {NOTHING_LEARNT_DB} dB of what one \
                 constant colour per band scores on the same pixels ({c:.2} dB): the field learnt little of the \
                 scene (too few steps, wrong poses, images that disagree{})",
                if small.is_some() { ", values too small for the colour head" } else { "" }
            );
            log::warn!("{note}");
            summary.notes.push(note);
        }
    }
    let s = serde_json::to_string_pretty(&summary).expect("json");
    write_atomic_str(&run.join("summary.json"), s.as_bytes())?;
    Ok(summary)
}

/// How far through its run a step is, for `optimizer.schedule: run`: the larger of `step / max_steps` and
/// `elapsed_s / time_budget_s` (when there is a budget), clamped to [0, 1].
pub fn run_progress(step: u64, max_steps: u64, elapsed_s: f64, time_budget_s: Option<f64>) -> f64 {
    let by_steps = if max_steps == 0 { 1.0 } else { step as f64 / max_steps as f64 };
    let by_time = time_budget_s.filter(|t| *t > 0.0).map_or(0.0, |t| elapsed_s / t);
    by_steps.max(by_time).clamp(0.0, 1.0)
}

/// What the trainer does with each completed step's results: the metrics log, the NaN guard's count, the progress
/// bar and the GPU-time totals of the profiled steps.
struct StepLog {
    metrics: std::fs::File,
    path: PathBuf,
    bar: Option<indicatif::ProgressBar>,
    checkpoints: PathBuf,
    rays_per_batch: usize,
    max_steps: u64,
    poisoned_in_a_row: u32,
    /// Steps that were not skipped, and the buffer named by the first skipped one (a run that trained nothing fails).
    good: u64,
    first_poisoned: Option<String>,
    last: StepStats,
    completed: u64,
    rays_done: u64,
    kernel_totals: Vec<KernelTime>,
    gpu_ms_total: f64,
    profiled_steps: u64,
    /// When the previous results arrived (the per-step time logged is the time between arrivals).
    last_arrival: Instant,
    /// The random-background warm-up's guard, and the warm-up end it asks for after a collapse.
    guard: Option<BackgroundGuard>,
    rewarm_to: Option<u64>,
}

impl StepLog {
    fn new(
        metrics: std::fs::File,
        path: PathBuf,
        bar: Option<indicatif::ProgressBar>,
        checkpoints: PathBuf,
        (rays_per_batch, max_steps): (usize, u64),
    ) -> Self {
        Self {
            metrics,
            path,
            bar,
            checkpoints,
            rays_per_batch,
            max_steps,
            poisoned_in_a_row: 0,
            good: 0,
            first_poisoned: None,
            last: StepStats::default(),
            completed: 0,
            rays_done: 0,
            kernel_totals: Vec::new(),
            gpu_ms_total: 0.0,
            profiled_steps: 0,
            last_arrival: Instant::now(),
            guard: None,
            rewarm_to: None,
        }
    }

    fn log(&mut self, v: serde_json::Value) -> NerfResult<()> {
        writeln!(self.metrics, "{v}").and_then(|_| self.metrics.flush()).map_err(|e| NerfError::file(&self.path, e))
    }

    /// Takes completed steps in order; MAX_POISONED_STEPS poisoned steps in a row stop training with an error that
    /// names the step and the buffer.
    fn take(&mut self, done: Vec<StepStats>, state: &mut TrainerState) -> NerfResult<()> {
        if done.is_empty() {
            return Ok(());
        }
        let ms = self.last_arrival.elapsed().as_secs_f64() * 1e3 / done.len() as f64;
        self.last_arrival = Instant::now();
        for stats in done {
            state.step = stats.step + 1;
            self.completed += 1;
            if stats.profiled {
                self.profiled_steps += 1;
                self.gpu_ms_total += stats.timing.gpu_ms;
                add_kernel_times(&mut self.kernel_totals, &stats.timing);
            }
            if stats.skipped {
                self.poisoned_in_a_row += 1;
                let what = stats.poisoned.clone().unwrap_or_default();
                self.first_poisoned.get_or_insert_with(|| what.clone());
                self.log(serde_json::json!({"step": stats.step, "skipped": true, "poisoned_buffer": what}))?;
                if self.poisoned_in_a_row >= MAX_POISONED_STEPS {
                    return Err(NerfError::NonFinite {
                        step: stats.step,
                        buffer: what,
                        count: MAX_POISONED_STEPS,
                        checkpoints: self.checkpoints.clone(),
                    });
                }
                continue;
            }
            self.poisoned_in_a_row = 0;
            self.good += 1;
            let rays_per_s = self.rays_per_batch as f64 / (ms.max(1e-9) / 1e3);
            if stats.step % 10 == 0 || state.step == self.max_steps {
                self.log(serde_json::json!({
                    "step": stats.step, "loss": stats.loss, "loss_rgb": stats.loss_rgb, "loss_distortion": stats.loss_distortion,
                    "loss_interlevel": stats.loss_interlevel, "loss_depth": stats.loss_depth, "psnr": stats.psnr, "step_ms": ms, "rays_per_s": rays_per_s,
                    "proposals_updated": stats.proposals_updated, "loss_pose": stats.loss_pose, "lr_fields": stats.lr_fields,
                }))?;
            }
            if let Some(b) = &self.bar {
                b.set_position(state.step);
                b.set_message(format!("{rays_per_s:.0} rays/s loss {:.4} psnr {:.2}", stats.loss, stats.psnr));
            }
            if let Some(end) =
                self.guard.as_mut().and_then(|g| g.observe(stats.step, stats.loss_rgb, stats.loss_distortion))
            {
                self.rewarm_to = Some(end);
                let note = self.guard.as_ref().and_then(|g| g.notes.last().cloned()).unwrap_or_default();
                log::warn!("{note}");
                self.log(serde_json::json!({"step": stats.step, "background_rewarm_until": end}))?;
            }
            self.last = stats;
        }
        Ok(())
    }
}

fn write_atomic_str(path: &Path, bytes: &[u8]) -> NerfResult<()> {
    atomic::write_bytes(path, bytes).map_err(|e| NerfError::file(path, e))
}
