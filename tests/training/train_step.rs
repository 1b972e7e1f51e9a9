//! One whole training step on the GPU against the CPU reference pipeline (`msnerf::reference::pipeline`): the loss
//! terms and every parameter gradient (hash grids, MLPs, appearance embeddings, camera pose corrections; proposals on
//! update steps only), with and without depth supervision (`loss.depth`, both losses).
//! Gradients are judged per slot on the 99th percentile of |gpu - ref| / (|ref| + 1e-3 max|ref|) (2e-3 for the NeRF
//! field, 1e-2 for proposals): fp32 against f64, atomics in any order, and sample positions that move by float rounding
//! across hash cells make a few outliers.

use crate::common;
use common::{gpu, rng};
use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::nerf::config::{ActivationStorage, ModelConfig};
use msnerf::nerf::model::{Model, POSE_SLOT};
use msnerf::nerf::pipeline::{Batch, Pipeline};
use msnerf::nerf::rays::GpuCamera;
use msnerf::reference::pipeline::{train_step, RefRay};
use rand::Rng;

fn small_config() -> ModelConfig {
    let mut c = common::small_tiny_config();
    c.field.appearance_embed_dim = 4;
    c.trainer.rays_per_chunk = 20;
    c
}

fn cameras() -> (Vec<Camera>, Vec<[[f32; 4]; 3]>) {
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
    // Three cameras on a ring at radius 0.9 looking at the origin (OpenGL: looking along -z).
    let poses = (0..3)
        .map(|i| {
            let a = i as f32 * 2.1;
            let pos = [0.9 * a.cos(), 0.9 * a.sin(), 0.3];
            let z = {
                let l = (pos[0] * pos[0] + pos[1] * pos[1] + pos[2] * pos[2]).sqrt();
                pos.map(|v| v / l)
            }; // back
            let x = {
                let v = [-z[1], z[0], 0.0f32];
                let l = (v[0] * v[0] + v[1] * v[1]).sqrt();
                v.map(|c| c / l)
            };
            let y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
            [[x[0], y[0], z[0], pos[0]], [x[1], y[1], z[1], pos[1]], [x[2], y[2], z[2], pos[2]]]
        })
        .collect();
    (vec![cam; 3], poses)
}

fn check_step(update: bool, seed: u64) {
    check_step_with(update, seed, |_| {});
}

/// Returns the step's RGB loss (GPU).
fn check_step_with(update: bool, seed: u64, tweak: impl Fn(&mut ModelConfig)) -> f64 {
    check_step_full(update, seed, false, tweak)
}

/// `rig`: the camera table also holds a band camera per frame (the frame's pose moved 5 cm along its x axis, as
/// `rig_cameras` makes them), every other ray comes from one and observes one band (NaN targets for the others),
/// and its pose correction and appearance are its frame's (`Batch::cameras`).
fn check_step_full(update: bool, seed: u64, rig: bool, tweak: impl Fn(&mut ModelConfig)) -> f64 {
    check_step_model(update, seed, rig, tweak, |_| {})
}

/// `check_step_full` with `model_tweak` applied to the model once it is built.
fn check_step_model(
    update: bool,
    seed: u64,
    rig: bool,
    tweak: impl Fn(&mut ModelConfig),
    model_tweak: impl Fn(&mut Model),
) -> f64 {
    let g = gpu();
    let mut cfg = small_config();
    tweak(&mut cfg);
    let bands = 6;
    let (cams, poses) = cameras();
    let mut model = Model::new(&g, &cfg, bands, cams.len()).expect("model");
    model_tweak(&mut model);
    // Larger hash values than the U(-1e-4, 1e-4) init, so densities and gradients are not negligible; the NeRF
    // field gets sharper densities than the proposals, so both proposal levels see an interlevel loss.
    let mut r = rng(seed);
    for slot in model.store.slots().to_vec() {
        if slot.name.ends_with("grid") {
            let a = if slot.name.starts_with("field") { 2.0f32 } else { 0.05 };
            let v: Vec<f32> = (0..slot.len).map(|_| r.random_range(-a..a)).collect();
            model.store.upload_slot(model.store.params(), &slot, &v).expect("upload");
        }
        if slot.name == POSE_SLOT {
            // Corrections of a few centimetres and degrees; the last camera's rotation sits under the exp map's
            // theta floor of 0.01 (its coefficients are constants there).
            let mut v: Vec<f32> =
                (0..slot.len).map(|i| r.random_range(-0.05f32..0.05) * [0.6, 1.0][i % 6 / 3]).collect();
            let last = v.len() - 3;
            v[last..].copy_from_slice(&[0.004, -0.003, 0.005]);
            model.store.upload_slot(model.store.params(), &slot, &v).expect("upload");
        }
    }
    let params: Vec<f64> = model.store.params().download(&g).expect("params").iter().map(|&v| v as f64).collect();
    let band_poses: Vec<[[f32; 4]; 3]> = poses
        .iter()
        .map(|p| {
            let mut q = *p;
            for row in &mut q {
                row[3] += 0.05 * row[0];
            }
            q
        })
        .collect();
    let mut table: Vec<GpuCamera> = cams.iter().zip(&poses).map(|(c, p)| GpuCamera::new(c, p)).collect();
    if rig {
        table.extend(cams.iter().zip(&band_poses).map(|(c, p)| GpuCamera::new(c, p)));
    }
    let mut pipe = Pipeline::new(&g, model, &table).expect("pipeline");
    if !update {
        pipe.step = 50; // past the always-update warm-up; the schedule's counter is 0, so no update
    }
    let n = 37;
    let mut batch = Batch::default();
    let mut refs = Vec::new();
    for i in 0..n {
        let (cam, row, col) = (i % 3, r.random_range(0..48u32), r.random_range(0..64u32));
        let rig_ray = rig && i % 2 == 0;
        batch.pixels.extend([if rig_ray { 3 + cam as u32 } else { cam as u32 }, row, col]);
        if rig {
            batch.cameras.push(cam as u32);
        }
        let mut target: Vec<f32> = (0..bands).map(|_| r.random_range(0.0f32..1.0)).collect();
        if rig_ray {
            for (b, t) in target.iter_mut().enumerate() {
                if b != i % bands {
                    *t = f32::NAN;
                }
            }
        }
        let weight = if i % 9 == 4 { 0.0 } else { 1.0 };
        batch.targets.extend(&target);
        batch.targets.push(weight);
        let ray = cams[cam].ray_f32(if rig_ray { &band_poses[cam] } else { &poses[cam] }, row, col);
        // With depth supervision: a target near the scene centre's distance on most rays, none on every fifth.
        let depth = cfg.loss.depth.and_then(|_| {
            let centre = ray.origin.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
            let target = (i % 5 != 2).then(|| (centre * r.random_range(0.8..1.8), r.random_range(0.1..0.5)));
            let (d, s) = target.unwrap_or((0.0, 1.0));
            batch.depth.extend([d as f32, s as f32]);
            target.map(|(d, s)| ((d as f32) as f64, (s as f32) as f64))
        });
        refs.push(RefRay {
            origin: ray.origin.map(|v| v as f64),
            dir: ray.direction.map(|v| v as f64),
            camera: cam,
            target: target.iter().map(|&v| v as f64).collect(),
            weight: weight as f64,
            depth,
        });
    }
    // The warm-up compiles every kernel and changes nothing the step below depends on.
    pipe.warm_up().expect("warm-up");
    let compiled = g.pipeline_count();
    let step = pipe.step;
    let stats = pipe.train_step(&batch).expect("train step");
    assert_eq!(g.pipeline_count(), compiled, "the warm-up created every pipeline a training step uses");
    assert_eq!(stats.proposals_updated, update);
    assert!(!stats.skipped, "no NaN in a healthy step: {:?}", stats.poisoned);
    let want = train_step(&pipe.model, &params, &refs, step, update);
    // fp16 hidden activations: the GPU's fp32 sums and the twin's f64 ones round a few activations to neighbouring
    // halves, so every tolerance is 10x looser (the kernel tests' fp16 tolerances are 100x looser).
    let loose = if cfg.mlp_activations == ActivationStorage::F16 { 10.0 } else { 1.0 };
    let close =
        |a: f64, b: f64, what: &str| assert!((a - b).abs() <= 1e-4 * loose * b.abs() + 1e-9, "{what}: gpu {a} ref {b}");
    close(stats.loss_rgb, want.loss_rgb, "rgb loss");
    close(stats.loss_distortion, want.loss_distortion, "distortion loss");
    close(stats.loss_interlevel, want.loss_interlevel, "interlevel loss");
    close(stats.loss_pose, want.loss_pose, "pose regulariser");
    close(stats.loss_depth, want.loss_depth, "depth loss");
    assert_eq!(want.loss_depth != 0.0, cfg.loss.depth.is_some(), "depth loss {}", want.loss_depth);
    assert_eq!(want.loss_pose > 0.0, cfg.camera_optimizer.enabled());
    assert_eq!(want.loss_interlevel > 0.0, update);
    let grads = pipe.model.store.grads().download(&g).expect("grads");
    let mut zero_slots = Vec::new();
    for slot in pipe.model.store.slots() {
        let (gpu_g, ref_g) = (&grads[slot.range()], &want.grads[slot.range()]);
        let scale = ref_g.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let is_prop = slot.name.starts_with("proposal");
        if is_prop && !update {
            assert!(gpu_g.iter().all(|&v| v == 0.0), "{}: no proposal gradient on a non-update step", slot.name);
            continue;
        }
        if scale == 0.0 {
            // A level whose weights already bound the NeRF weights everywhere has no interlevel gradient.
            assert!(
                gpu_g.iter().all(|&v| v.abs() < 1e-12),
                "{}: the reference gradient is zero, the GPU's is not",
                slot.name
            );
            zero_slots.push(slot.name.clone());
            continue;
        }
        let mut rel: Vec<f64> = (0..slot.len)
            .filter(|&i| ref_g[i] != 0.0 || gpu_g[i] != 0.0)
            .map(|i| (gpu_g[i] as f64 - ref_g[i]).abs() / (ref_g[i].abs() + 1e-3 * scale))
            .collect();
        rel.sort_by(f64::total_cmp);
        let p99 = rel[(rel.len() * 99) / 100];
        // Proposal gradients come through the interlevel loss, whose NeRF edges are resampled from fp32 weights on the
        // GPU and f64 weights here: with sharp densities a few edges, hence sample positions, move across hash cells.
        let tol = if is_prop { 1e-2 } else { 2e-3 } * loose;
        assert!(p99 < tol, "{}: 99th percentile relative gradient error {p99:e} over {} entries", slot.name, rel.len());
    }
    assert!(
        zero_slots.iter().all(|s| s.starts_with("proposal")),
        "only a proposal level may have no gradient: {zero_slots:?}"
    );
    assert!(
        zero_slots.len() < 2 * pipe.model.proposals.len(),
        "some proposal level must receive gradients: {zero_slots:?}"
    );
    stats.loss_rgb
}

#[test]
fn whole_step_matches_reference_on_a_proposal_update_step() {
    for seed in [11, 13, 14] {
        check_step(true, seed);
    }
}

#[test]
fn whole_step_matches_reference_without_proposal_update() {
    check_step(false, 12);
}

#[test]
fn whole_step_matches_reference_with_gradient_scaling() {
    check_step_with(true, 11, |c| c.loss.gradient_scaling = true);
}

#[test]
fn whole_step_matches_reference_with_random_background() {
    check_step_with(false, 12, |c| c.rendering.background = msnerf::nerf::config::Background::Random);
}

/// `rendering.random_background_steps`: the steps before it train with the `random` background on both sides (the
/// same loss as `background: random`), the step at it with `background` again (the same loss as without the warm-up).
#[test]
fn whole_step_matches_reference_through_a_random_background_warm_up() {
    use msnerf::nerf::config::Background;
    // check_step_with(false, ..) trains step 50.
    let random = check_step_with(false, 12, |c| c.rendering.background = Background::Random);
    let last = check_step_with(false, 12, |_| {});
    let warm = check_step_with(false, 12, |c| c.rendering.random_background_steps = 51);
    let after = check_step_with(false, 12, |c| c.rendering.random_background_steps = 50);
    assert!((random - last).abs() > 1e-3 * last, "the backgrounds give different losses: {random} {last}");
    // The same inputs: equal up to the order of the loss's float sums.
    assert!((warm - random).abs() <= 1e-5 * random, "step 50 of a 51-step warm-up trains with random: {warm} {random}");
    assert!(
        (after - last).abs() <= 1e-5 * last,
        "step 50 after a 50-step warm-up trains with last_sample: {after} {last}"
    );
}

/// GPUs choose a hash grid's kernels by the pass size (one dispatch for all levels up to a limit, one per level
/// above). With the limit at the field grid's points in the batch's short second pass (17 of 37 rays; passes of 20),
/// one step runs both: the warm-up must build both kinds of pipeline (`check_step_model` counts them), and the step
/// still matches the f64 reference.
#[test]
fn whole_step_matches_reference_with_hash_grids_chosen_by_pass_size() {
    for update in [true, false] {
        check_step_model(
            update,
            31,
            false,
            |_| {},
            |m: &mut Model| m.set_hash_one_dispatch_max(17 * m.cfg.sampling.num_nerf_samples),
        );
    }
}

#[test]
fn whole_step_matches_reference_with_pose_refinement() {
    use msnerf::nerf::config::CameraOptMode;
    for (update, seed) in [(true, 13), (false, 12)] {
        check_step_with(update, seed, |c| c.camera_optimizer.mode = CameraOptMode::SO3xR3);
    }
}

/// `field.direction_sh_degree: 2`: 4 of the 16 SH columns, the rest zero in the colour MLP's input and left out of
/// the view direction's pose gradient (pose refinement on, so both paths are checked).
#[test]
fn whole_step_matches_reference_with_sh_degree_2() {
    use msnerf::nerf::config::CameraOptMode;
    check_step_with(false, 12, |c| {
        c.field.direction_sh_degree = 2;
        c.camera_optimizer.mode = CameraOptMode::SO3xR3;
    });
}

/// `field.coarse_to_fine`: at step 50 of a fade until step 80 from all levels but the finest, that level is weighted
/// 0.625, in the forward, the parameter gradient and, with pose refinement, the input gradient. (Fewer levels make
/// the field too smooth for the step's interlevel-loss checks.)
#[test]
fn whole_step_matches_reference_with_coarse_to_fine_levels() {
    use msnerf::nerf::config::{CameraOptMode, CoarseToFine};
    for (update, seed, pose) in [(true, 11, false), (false, 12, true)] {
        check_step_with(update, seed, |c| {
            c.field.coarse_to_fine = Some(CoarseToFine { levels: c.field.grid.n_levels - 1, until_step: 80 });
            let active = c.field.active_levels_at(50);
            assert!(active > 1.0 && active < c.field.grid.n_levels as f32 && active.fract() > 0.0, "{active}");
            if pose {
                c.camera_optimizer.mode = CameraOptMode::SO3xR3;
            }
        });
    }
}

/// `field.coarse_to_fine`: off by default (every level, not written into a run's config), a linear fade between
/// its `levels` and all of them over `until_step` steps, refused by key when out of range.
#[test]
fn coarse_to_fine_schedules_and_validates() {
    use msnerf::nerf::config::{CoarseToFine, ModelConfig};
    let mut c = ModelConfig::resolve("demo").expect("demo");
    let all = c.field.grid.n_levels as f32;
    assert_eq!(c.field.coarse_to_fine, None);
    assert!(!serde_yaml::to_string(&c).unwrap().contains("coarse_to_fine"));
    assert_eq!((c.field.active_levels_at(0), c.field.active_levels_at(10_000)), (all, all));
    c.field.coarse_to_fine = Some(CoarseToFine { levels: 4, until_step: 2000 });
    c.validate().expect("valid");
    for (step, want) in [(0, 4.0), (1000, 4.0 + (all - 4.0) / 2.0), (2000, all), (5000, all)] {
        assert!(
            (c.field.active_levels_at(step) - want).abs() < 1e-5,
            "step {step}: {}",
            c.field.active_levels_at(step)
        );
    }
    assert!(serde_yaml::to_string(&c).unwrap().contains("coarse_to_fine"));
    for bad in [
        CoarseToFine { levels: 0, until_step: 10 },
        CoarseToFine { levels: 13, until_step: 10 },
        CoarseToFine { levels: 2, until_step: 0 },
    ] {
        c.field.coarse_to_fine = Some(bad);
        let e = c.validate().expect_err("out of range").to_string();
        assert!(e.contains("field.coarse_to_fine"), "{e}");
    }
}

/// `field.direction_sh_degree`: nerfacto's 4 by default (and not written into a run's config then), 1..=4 accepted,
/// anything else refused by key.
#[test]
fn direction_sh_degree_defaults_and_validates() {
    use msnerf::nerf::config::ModelConfig;
    let mut c = ModelConfig::resolve("nerfacto").expect("nerfacto");
    assert_eq!((c.field.direction_sh_degree, c.field.sh_count()), (4, 16));
    assert!(!serde_yaml::to_string(&c).unwrap().contains("direction_sh_degree"));
    for d in 1..=4 {
        c.field.direction_sh_degree = d;
        c.validate().unwrap_or_else(|e| panic!("degree {d}: {e}"));
        assert_eq!(c.field.sh_count(), d * d);
    }
    c.field.direction_sh_degree = 2;
    assert!(serde_yaml::to_string(&c).unwrap().contains("direction_sh_degree: 2"));
    for d in [0, 5] {
        c.field.direction_sh_degree = d;
        let e = c.validate().expect_err("out of range").to_string();
        assert!(e.contains("field.direction_sh_degree"), "{e}");
    }
}

#[test]
fn whole_step_matches_reference_with_rig_rays() {
    use msnerf::nerf::config::CameraOptMode;
    check_step_full(true, 11, true, |_| {});
    check_step_full(false, 13, true, |c| c.camera_optimizer.mode = CameraOptMode::SO3xR3);
}

#[test]
fn whole_step_matches_reference_with_fp16_activations() {
    // The twin rounds the hidden activations to fp16 where the kernels store them, so the step still matches.
    check_step_with(true, 13, |c| c.mlp_activations = ActivationStorage::F16);
}

#[test]
fn whole_step_matches_reference_with_depth_supervision() {
    use msnerf::nerf::config::{DepthLoss, DepthSource, DepthSupervision};
    for (loss, update, seed) in [(DepthLoss::DsNerf, true, 11), (DepthLoss::Urf, false, 12)] {
        check_step_with(update, seed, |c| {
            c.loss.depth = Some(DepthSupervision {
                loss,
                source: DepthSource::SparsePoints,
                mult: 0.1,
                sigma: 0.1,
                ray_fraction: 0.0,
                when: Default::default(),
            })
        });
    }
}

/// `loss.distortion_ramp`: off by default (the constant weight at every step), linear between its steps when set,
/// and refused when its steps are out of order.
#[test]
fn distortion_ramp_interpolates_and_validates() {
    use msnerf::nerf::config::{DistortionRamp, ModelConfig};
    let mut c = ModelConfig::resolve("tiny").expect("tiny");
    assert_eq!(c.loss.distortion_ramp, None);
    for s in [0, 500, 100_000] {
        assert_eq!(c.loss.distortion_at(s), c.loss.distortion_mult);
    }
    c.loss.distortion_mult = 0.002;
    c.loss.distortion_ramp = Some(DistortionRamp { from_step: 100, to_step: 300, mult: 0.01 });
    assert_eq!(c.loss.distortion_at(50), 0.002);
    assert!((c.loss.distortion_at(200) - 0.006).abs() < 1e-7);
    assert_eq!(c.loss.distortion_at(300), 0.01);
    assert_eq!(c.loss.distortion_at(5000), 0.01);
    c.validate().expect("a valid ramp");
    c.loss.distortion_ramp = Some(DistortionRamp { from_step: 300, to_step: 300, mult: 0.01 });
    let e = c.validate().expect_err("empty ramp").to_string();
    assert!(e.contains("loss.distortion_ramp"), "{e}");
}

/// `rendering.random_background_steps`: off by default (and not written into a run's config then; the `demo`
/// profile sets 300), `random` before it in training only, refused by key after `background: random`.
#[test]
fn random_background_warm_up_schedules_and_validates() {
    use msnerf::nerf::config::{Background, ModelConfig};
    let mut off = ModelConfig::resolve("tiny").expect("tiny");
    off.rendering.background = Background::LastSample;
    assert_eq!(off.rendering.random_background_steps, 0);
    assert!(!serde_yaml::to_string(&off).unwrap().contains("random_background_steps"));
    assert_eq!(off.rendering.background_at(0, true), Background::LastSample);
    let mut c = ModelConfig::resolve("demo").expect("demo");
    assert_eq!(c.rendering.random_background_steps, 300);
    assert!(serde_yaml::to_string(&c).unwrap().contains("random_background_steps: 300"));
    for (step, train, want) in [
        (0, true, Background::Random),
        (299, true, Background::Random),
        (300, true, Background::LastSample),
        (0, false, Background::LastSample),
    ] {
        assert_eq!(c.rendering.background_at(step, train), want, "step {step}, train {train}");
    }
    c.validate().expect("a valid warm-up");
    let text = serde_yaml::to_string(&c).unwrap();
    assert!(text.contains("random_background_steps: 300"), "{text}");
    c.rendering.background = Background::Random;
    let e = c.validate().expect_err("warm-up before random").to_string();
    assert!(e.contains("rendering.random_background_steps"), "{e}");
}

/// Every built-in profile parses; an unknown name is refused with the built-in list, a file path keeps its name.
#[test]
fn model_profiles_resolve_by_name_or_file() {
    use msnerf::nerf::config::ModelConfig;
    for (name, _) in ModelConfig::BUILTIN {
        ModelConfig::resolve(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(ModelConfig::is_builtin(name));
    }
    let e = ModelConfig::resolve("nerfacto2").expect_err("unknown").to_string();
    assert!(e.starts_with("nerfacto2: no such model profile") && e.contains("multispectral-nerf"), "{e}");
    let e = ModelConfig::resolve("/no/such/profile.yaml").expect_err("missing file").to_string();
    assert!(e.contains("/no/such/profile.yaml"), "{e}");
}
