//! The trainer's NaN/Inf step guard (src/nerf/pipeline.rs `train_step`, src/nerf/trainer.rs): a poisoned step is
//! skipped (no Adam step: parameters and moments unchanged) and names the first poisoned buffer in pipeline order;
//! MAX_POISONED_STEPS (5) poisoned steps in a row stop training with an error that says so and names the buffer.
//! What breaks without it: one NaN gradient reaches Adam, which writes NaN into the parameters and both moments, and
//! every later step is NaN (nerfacto.md §8.2-8.3; torch's GradScaler skips such steps the same way).

use crate::common;
use crate::data_support;
use common::{gpu, rng};
use data_support::TempDir;
use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::data::{load_dataset, LoadOptions};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::model::Model;
use msnerf::nerf::pipeline::{Batch, Pipeline};
use msnerf::nerf::rays::GpuCamera;
use msnerf::nerf::schedule::ProposalSchedule;
use msnerf::nerf::trainer::{self, TrainOptions, TrainerState, MAX_POISONED_STEPS};
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use rand::Rng;

fn small_config() -> ModelConfig {
    let mut c = common::small_tiny_config();
    c.trainer.rays_per_batch = 32;
    c.trainer.rays_per_chunk = 32;
    c.trainer.eval_rays_per_chunk = 64;
    c
}

fn pipeline(g: &msnerf::gpu::Context, bands: usize) -> Pipeline {
    let cfg = small_config();
    let cam = Camera {
        model: CameraModel::Pinhole,
        fx: 40.0,
        fy: 40.0,
        cx: 32.0,
        cy: 24.0,
        width: 64,
        height: 48,
        distortion: Distortion::default(),
    };
    let c2w: [[f32; 4]; 3] = [[1.0, 0.0, 0.0, 0.1], [0.0, 0.0, -1.0, -0.8], [0.0, 1.0, 0.0, 0.2]];
    let model = Model::new(g, &cfg, bands, 1).expect("model");
    Pipeline::new(g, model, &[GpuCamera::new(&cam, &c2w)]).expect("pipeline")
}

fn batch(bands: usize, n: usize, seed: u64) -> Batch {
    let mut r = rng(seed);
    let mut b = Batch::default();
    for _ in 0..n {
        b.pixels.extend([0, r.random_range(0..48u32), r.random_range(0..64u32)]);
        b.targets.extend((0..bands).map(|_| r.random_range(0.0f32..1.0)));
        b.targets.push(1.0);
    }
    b
}

fn state(p: &Pipeline) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let s = &p.model.store;
    (s.params().download(&p.ctx).expect("p"), s.m().download(&p.ctx).expect("m"), s.v().download(&p.ctx).expect("v"))
}

/// A NaN target, then NaN parameters in the NeRF field's grid and in proposal 0's grid: each step is skipped, names
/// its buffer, and leaves parameters and Adam moments bitwise unchanged; a clean step afterwards trains normally.
#[test]
fn poisoned_steps_are_skipped_and_name_the_buffer() {
    let g = gpu();
    let bands = 3;
    let mut p = pipeline(&g, bands);
    let clean = batch(bands, 32, 1);
    let s = p.train_step(&clean).expect("step");
    assert!(!s.skipped, "{:?}", s.poisoned);

    // A NaN target is a band the ray did not observe (rig-aware training): the step goes on.
    let mut unobserved = batch(bands, 32, 3);
    unobserved.band_targets_mut(5)[1] = f32::NAN;
    let s = p.train_step(&unobserved).expect("step");
    assert!(!s.skipped && s.loss.is_finite(), "a NaN target is not observed, not poison: {s:?}");

    // An infinite target value (a corrupt pixel): the loss and every gradient are non-finite.
    let mut bad = batch(bands, 32, 2);
    bad.band_targets_mut(5)[1] = f32::INFINITY;
    let before = state(&p);
    let step0 = p.step;
    let s = p.train_step(&bad).expect("step");
    assert!(s.skipped && !s.loss.is_finite(), "infinite target skipped: {s:?}");
    assert_eq!(s.poisoned.as_deref(), Some("ray outputs"));
    assert_eq!(p.step, step0 + 1, "a skipped step still counts");
    assert!(state(&p) == before, "a skipped step changes no parameter or moment");

    // NaN parameters (what a bad Adam step or a bad checkpoint would leave behind).
    for (slot, name) in [("field.grid", "nerf encoding"), ("proposal0.grid", "proposal 0 encoding")] {
        let store = &p.model.store;
        let sl = store.slot(slot).unwrap_or_else(|| panic!("slot {slot}")).clone();
        let good = store.download_slot(store.params(), &sl).expect("download");
        store.upload_slot(store.params(), &sl, &vec![f32::NAN; sl.len]).expect("poison");
        let before = state(&p);
        let s = p.train_step(&clean).expect("step");
        assert!(s.skipped, "{slot}: skipped");
        assert_eq!(s.poisoned.as_deref(), Some(name), "{slot}: names the first poisoned buffer");
        let after = state(&p);
        assert!(after.1 == before.1 && after.2 == before.2, "{slot}: moments untouched");
        let store = &p.model.store;
        store.upload_slot(store.params(), &sl, &good).expect("restore");
    }
    let s = p.train_step(&clean).expect("step");
    assert!(!s.skipped && s.loss.is_finite(), "training goes on after the poison is gone: {s:?}");
}

/// MAX_POISONED_STEPS poisoned steps in a row stop `train` with an error naming the count and the buffer. The poison:
/// a checkpoint whose density MLP weights are NaN, resumed.
#[test]
fn five_poisoned_steps_in_a_row_stop_training_with_a_clear_error() {
    assert_eq!(MAX_POISONED_STEPS, 5);
    let td = TempDir::new("stab_guard");
    let data = td.path().join("ds");
    let scene = SceneDesc::load("ci-small").expect("ci-small scene");
    let opts = SimOptions { width: Some(24), height: Some(18), views: Some(6), points: 1000, ..SimOptions::default() };
    simulate(&scene, &opts, &data).unwrap_or_else(|e| panic!("{e}"));
    let ds = load_dataset(&data, &LoadOptions::default()).expect("dataset");
    let mut cfg = small_config();
    cfg.trainer.max_steps = 50;
    cfg.trainer.steps_per_eval = 1000;
    cfg.trainer.steps_per_save = 1000;
    let run = td.path().join("run");
    let g = gpu();
    // A checkpoint at step 3 with NaN density-MLP weights.
    let model = Model::new(&g, &cfg, ds.n_bands(), ds.frames.len()).expect("model");
    let sl = model.store.slot("field.mlp").expect("density mlp").clone();
    model.store.upload_slot(model.store.params(), &sl, &vec![f32::NAN; sl.len]).expect("poison");
    std::fs::create_dir_all(run.join("checkpoints")).expect("mkdir");
    model.store.save(&run.join("checkpoints/latest.msnp")).expect("save");
    let st = TrainerState { step: 3, schedule: ProposalSchedule::default(), best_eval_psnr: None, elapsed_s: 0.0 };
    std::fs::write(run.join("checkpoints/latest.json"), serde_json::to_string(&st).expect("json")).expect("state");
    let opts = TrainOptions {
        data: data.clone(),
        model: cfg,
        out: run.clone(),
        resume: true,
        time_budget_s: None,
        host_budget_bytes: 64 << 20,
        resample_every: 100,
        eval_pixels: 64,
        progress: false,
        stop: None,
        bands: None,
    };
    let err = trainer::train(&g, &opts).expect_err("training must stop");
    assert!(
        matches!(&err, msnerf::nerf::NerfError::NonFinite { step: 7, count: 5, buffer, .. } if buffer.contains("nerf density")),
        "a typed NaN-guard error: {err:?}"
    );
    let err = err.to_string();
    assert!(err.contains("5 steps in a row produced NaN/Inf"), "{err}");
    assert!(err.contains("nerf density") && err.contains("step 7"), "names the buffer and the step: {err}");
    assert!(err.contains("checkpoints"), "points at the last good checkpoint: {err}");
    let log = std::fs::read_to_string(run.join("metrics.jsonl")).expect("metrics");
    let skipped: Vec<&str> = log.lines().filter(|l| l.contains("\"skipped\":true")).collect();
    assert_eq!(skipped.len(), 5, "{log}");
    assert!(skipped.iter().all(|l| l.contains("\"poisoned_buffer\":\"nerf density\"")), "{log}");

    // Fewer steps than the guard's limit, every one of them poisoned: the run fails instead of ending as trained.
    let mut opts = opts;
    opts.model.trainer.max_steps = 6;
    let err = trainer::train(&g, &opts).expect_err("a run that trained nothing fails");
    assert!(
        matches!(&err, msnerf::nerf::NerfError::NothingTrained { steps: 3, buffer } if buffer.contains("nerf density")),
        "a typed error naming the steps and the buffer: {err:?}"
    );
    assert!(err.to_string().contains("nothing was trained"), "{err}");
}
