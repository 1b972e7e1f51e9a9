//! Steps in flight (issue 22): a training step is one submission, and with `steps_in_flight` = 2 or 3 the host
//! records the next step while the device runs the last. The results must be those of one step at a time: the same
//! losses, step by step (1e-5 relative), and the same parameters (at most 0.5 % of them more than 1e-4 apart, each by
//! a few Adam steps at most: fp32 atomics add in any order on a GPU, and Adam amplifies that where a gradient is near
//! zero), and a
//! poisoned step in the middle of a pipelined run is still skipped on the device, named, and its optimiser counters
//! taken back.

use crate::common;
use common::{gpu, rng};
use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::model::Model;
use msnerf::nerf::pipeline::{Batch, Pipeline, StepStats};
use msnerf::nerf::rays::GpuCamera;
use rand::Rng;

const BANDS: usize = 4;

fn pipe(g: &msnerf::gpu::Context, in_flight: usize) -> Pipeline {
    let mut c = ModelConfig::resolve("tiny").expect("tiny model");
    c.field.grid.log2_hashmap_size = 11;
    c.field.grid.max_resolution = 128;
    c.trainer.rays_per_batch = 48;
    c.trainer.rays_per_chunk = 20; // three chunks per step, the last one short
    c.trainer.steps_in_flight = in_flight;
    let cam = Camera {
        model: CameraModel::Pinhole,
        fx: 50.0,
        fy: 50.0,
        cx: 40.0,
        cy: 30.0,
        width: 80,
        height: 60,
        distortion: Distortion::default(),
    };
    let cams: Vec<GpuCamera> = [0.4f32, -0.3]
        .iter()
        .map(|&x| GpuCamera::new(&cam, &[[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, 0.1], [0.0, 0.0, 1.0, 0.9]]))
        .collect();
    let model = Model::new(g, &c, BANDS, cams.len()).expect("model");
    let mut p = Pipeline::new(g, model, &cams).expect("pipeline");
    p.step = 200; // past the proposal warm-up: a mix of update and plain steps
    p
}

fn batches(n: usize, poison_at: Option<usize>) -> Vec<Batch> {
    let mut r = rng(31);
    (0..n)
        .map(|k| {
            let mut b = Batch::default();
            for _ in 0..48 {
                b.pixels.extend([r.random_range(0..2u32), r.random_range(0..60u32), r.random_range(0..80u32)]);
                b.targets.extend((0..BANDS).map(|_| r.random_range(0.0f32..1.0)));
                b.targets.push(1.0);
            }
            if poison_at == Some(k) {
                b.band_targets_mut(7)[2] = f32::INFINITY; // a corrupt value (NaN would mean "not observed")
            }
            b
        })
        .collect()
}

/// Steps taken one at a time (`train_step`).
fn one_at_a_time(g: &msnerf::gpu::Context, bs: &[Batch]) -> (Pipeline, Vec<StepStats>) {
    let mut p = pipe(g, 1);
    let stats = bs.iter().map(|b| p.train_step(b).expect("step")).collect();
    (p, stats)
}

/// Steps submitted `k` at a time, results collected as they come and at the end.
fn pipelined(g: &msnerf::gpu::Context, bs: &[Batch], k: usize) -> (Pipeline, Vec<StepStats>) {
    let mut p = pipe(g, k);
    let mut stats = Vec::new();
    for b in bs {
        p.submit_step(b).expect("submit");
        assert!(p.in_flight() <= k, "never more than {k} steps in flight");
        stats.extend(p.completed().expect("completed"));
    }
    stats.extend(p.flush().expect("flush"));
    assert_eq!(p.in_flight(), 0);
    (p, stats)
}

/// Parameters more than 1e-4 apart (relative, 1e-3 floor).
fn differing(a: &[f32], b: &[f32]) -> usize {
    a.iter().zip(b).filter(|(x, y)| (*x - *y).abs() > 1e-4 * (y.abs() + 1e-3)).count()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-5 * b.abs().max(1e-3)
}

#[test]
fn steps_in_flight_train_exactly_as_one_step_at_a_time() {
    let g = gpu();
    let bs = batches(8, None);
    let (p1, s1) = one_at_a_time(&g, &bs);
    let want = p1.model.store.params().download(&g).expect("params");
    let noise = differing(&one_at_a_time(&g, &bs).0.model.store.params().download(&g).expect("params"), &want);
    for k in [2, 3] {
        let (pk, sk) = pipelined(&g, &bs, k);
        assert_eq!(sk.iter().map(|s| s.step).collect::<Vec<_>>(), (200..208).collect::<Vec<_>>(), "in order");
        assert!(sk.iter().any(|s| s.proposals_updated) && sk.iter().any(|s| !s.proposals_updated));
        for (a, b) in sk.iter().zip(&s1) {
            assert_eq!(a.proposals_updated, b.proposals_updated, "step {}", a.step);
            for (x, y, what) in [
                (a.loss_rgb, b.loss_rgb, "rgb"),
                (a.loss_interlevel, b.loss_interlevel, "interlevel"),
                (a.loss_distortion, b.loss_distortion, "distortion"),
            ] {
                assert!(close(x, y), "{k} in flight, step {}: {what} loss {x} against {y}", a.step);
            }
        }
        // Float atomics add in whatever order the GPU schedules them, and Adam turns the sign of a near-zero
        // gradient into a whole lr-sized step. On lavapipe the runs agree exactly. On the H200, two runs one step
        // at a time differed in 1 parameter, and a run with steps in flight in about 650 of 316k (0.2 %), while every
        // loss agreed to 1e-5: the queue is busier, so the atomics land in another order. The bound is 0.5 % of the
        // parameters (or three times the one-at-a-time spread), each within a few Adam steps (lr 1e-2, 8 steps). A
        // broken pipeline (a step reading another step's rays, or losing its update) moves the losses and far more
        // parameters.
        let got = pk.model.store.params().download(&g).expect("params");
        let off = differing(&got, &want);
        let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        eprintln!(
            "{k} in flight: {off} of {} parameters differ (one at a time twice: {noise}), by at most {worst}",
            got.len()
        );
        assert!(
            off <= (3 * noise).max(got.len() / 200) && worst <= 0.2,
            "{k} in flight: {off} of {} parameters differ, by up to {worst} (one at a time twice: {noise})",
            got.len()
        );
        assert_eq!(pk.model.store.group_steps(), p1.model.store.group_steps());
        assert_eq!(pk.model.store.schedule_step(), p1.model.store.schedule_step());
    }
}

#[test]
fn a_poisoned_step_in_flight_is_skipped_named_and_its_counters_taken_back() {
    let g = gpu();
    let bs = batches(6, Some(3));
    let (p1, s1) = one_at_a_time(&g, &bs);
    let (p2, s2) = pipelined(&g, &bs, 2);
    for s in [&s1, &s2] {
        let skipped: Vec<u64> = s.iter().filter(|s| s.skipped).map(|s| s.step).collect();
        assert_eq!(skipped, [203], "only the poisoned step is skipped");
        assert_eq!(s[3].poisoned.as_deref(), Some("ray outputs"), "and it names the buffer");
        assert!(s.iter().filter(|s| !s.skipped).all(|s| s.loss.is_finite()));
    }
    // The device skipped the update; the host's counters end where one step at a time leaves them. (The one step
    // recorded while the verdict was pending used a bias correction one step ahead: docs/benchmarks.md.)
    assert_eq!(p2.model.store.group_steps(), p1.model.store.group_steps());
    assert_eq!(p2.model.store.schedule_step(), p1.model.store.schedule_step());
    let params = p2.model.store.params().download(&g).expect("params");
    assert!(params.iter().all(|v| v.is_finite()), "no NaN reached the parameters");
    // Up to the poisoned step, both runs are the same run.
    for (a, b) in s2.iter().zip(&s1).take(3) {
        assert!(close(a.loss_rgb, b.loss_rgb), "step {}", a.step);
    }
}

#[test]
fn steps_in_flight_is_checked_and_older_profiles_without_it_load() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/models/tiny.yaml")).expect("tiny");
    let without: String = text
        .lines()
        .filter(|l| !l.contains("steps_in_flight") && !l.contains("profile_every"))
        .collect::<Vec<_>>()
        .join("\n");
    let c = ModelConfig::parse(&without).expect("a profile written before the keys existed");
    assert_eq!((c.trainer.steps_in_flight, c.trainer.profile_every), (2, 10), "the defaults");
    for bad in [0, 4] {
        let e = ModelConfig::parse(&text.replace("steps_in_flight: 2", &format!("steps_in_flight: {bad}")))
            .expect_err("out of range")
            .to_string();
        assert!(e.contains("trainer.steps_in_flight must be 1, 2 or 3") && e.contains(&bad.to_string()), "{e}");
    }
}
