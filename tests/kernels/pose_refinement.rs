#![allow(clippy::needless_range_loop)] // index loops read as the formulas they check
//! Camera pose refinement (SO3xR3): the four kernels of `glsl/pose/` against their CPU twins
//! (`msnerf::reference::pose`), and the twins' backward passes against central finite differences in f64, in every
//! regime of the exp map (on its theta floor, its Taylor branch, its closed form, large angles) and of the contraction
//! (inside the unit cube, outside, on an axis tie).
//! Tolerances: values |a-b| <= 1e-5 + 1e-4|b|; kernel gradients (sums with cancellation, fp32 atomics in any order)
//! |a-b| <= 1e-4 (|b| + max|b|) + 1e-7; finite differences (h = 1e-6 in f64) |fd - analytic| <= 1e-6 (1 + |analytic|).

use crate::common;
use common::{gpu, rng};
use msnerf::gpu::{Context, GpuBuffer, LargeArray, MemoryCategory};
use msnerf::nerf::kernels::{Geometry, RayBuffers};
use msnerf::nerf::pose::{LevelGrad, PoseKernels, PoseSlot};
use msnerf::reference::pose as tw;
use msnerf::reference::render::{edge_to_t, hash_input};
use msnerf::reference::sh;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

fn up(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Activations, data).expect("upload")
}

fn check_vals(got: &[f32], want: &[f64], what: &str) {
    for i in 0..got.len() {
        assert!(common::close(got[i] as f64, want[i], 1e-5, 1e-4), "{what}[{i}]: got {} want {}", got[i], want[i]);
    }
}

fn check_grad(got: &[f32], want: &[f64], what: &str) {
    let scale = want.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for i in 0..got.len() {
        let (a, b) = (got[i] as f64, want[i]);
        assert!((a - b).abs() <= 1e-4 * (b.abs() + scale) + 1e-7, "{what}[{i}]: got {a} want {b} (scale {scale})");
    }
}

fn check_fd(analytic: f64, fd: f64, what: &str) {
    assert!((analytic - fd).abs() <= 1e-6 * (1.0 + analytic.abs()), "{what}: analytic {analytic} vs fd {fd}");
}

fn unit(r: &mut ChaCha8Rng) -> [f64; 3] {
    let v = [0, 1, 2].map(|_| r.random_range(-1.0..1.0f64));
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / l)
}

/// Rotation vectors in every regime of the exp map: on the theta floor, Taylor branch, closed form, large angle.
fn rotation_vectors(r: &mut ChaCha8Rng) -> Vec<[f64; 3]> {
    [0.004, 0.03, 0.09, 0.2, 1.3, 2.9].iter().map(|&m| unit(r).map(|v| v * m)).collect()
}

/// Central difference of f along coordinate k of x.
fn fd<const N: usize>(f: impl Fn([f64; N]) -> f64, x: [f64; N], k: usize) -> f64 {
    let h = 1e-6;
    let (mut a, mut b) = (x, x);
    a[k] += h;
    b[k] -= h;
    (f(a) - f(b)) / (2.0 * h)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[test]
fn exp_map_is_a_rotation_by_the_angle_about_the_axis() {
    let mut r = rng(1);
    for w in rotation_vectors(&mut r).into_iter().skip(1) {
        let theta = dot(w, w).sqrt();
        let axis = w.map(|v| v / theta);
        // A direction perpendicular to the axis turns by theta; the axis itself stays; lengths are kept.
        let p = unit(&mut r);
        let q = {
            let d = dot(p, axis);
            let v = [0, 1, 2].map(|k| p[k] - d * axis[k]);
            let l = dot(v, v).sqrt();
            v.map(|x| x / l)
        };
        let rq = tw::rotate(w, q);
        assert!((dot(rq, rq) - 1.0).abs() < 1e-12, "length kept at theta {theta}");
        assert!((dot(rq, q) - theta.cos()).abs() < 1e-12, "turned by theta {theta}");
        let ra = tw::rotate(w, axis);
        assert!((0..3).all(|k| (ra[k] - axis[k]).abs() < 1e-12), "the axis is fixed at theta {theta}");
    }
    // Series and closed form agree where they meet (theta = 0.1).
    let a: (f64, f64, f64, f64) = tw::so3_coeffs([0.0999999999, 0.0, 0.0]);
    let b = tw::so3_coeffs([0.1000000001, 0.0, 0.0]);
    for (x, y) in [(a.0, b.0), (a.1, b.1), (a.2, b.2), (a.3, b.3)] {
        assert!((x - y).abs() < 1e-9, "branches meet: {x} vs {y}");
    }
}

#[test]
fn rotation_gradient_matches_finite_differences() {
    let mut r = rng(2);
    for w in rotation_vectors(&mut r) {
        let d = unit(&mut r);
        let g = [0, 1, 2].map(|_| r.random_range(-1.0..1.0f64));
        let an = tw::rotate_grad_w(w, d, g);
        for k in 0..3 {
            let f = |w: [f64; 3]| dot(g, tw::rotate(w, d));
            check_fd(an[k], fd(f, w, k), &format!("dL/dw[{k}] at |w| = {:.3}", dot(w, w).sqrt()));
        }
    }
}

#[test]
fn contraction_gradient_matches_finite_differences() {
    let mut r = rng(3);
    let mut points: Vec<[f64; 3]> = (0..40).map(|_| [0, 1, 2].map(|_| r.random_range(-4.0..4.0f64))).collect();
    points.push([0.3, -0.2, 0.9]); // inside the unit cube
    points.push([5.0, -3.0, 1.0]); // outside, x the max-norm axis
    for x in points {
        let gh = [0, 1, 2].map(|_| r.random_range(-1.0..1.0f64));
        for contraction in [true, false] {
            let an = tw::hash_input_grad(x, gh, contraction);
            for k in 0..3 {
                let f = |x: [f64; 3]| dot(gh, hash_input(x, contraction).0);
                check_fd(an[k], fd(f, x, k), &format!("dL/dx[{k}] at {x:?} (contraction {contraction})"));
            }
        }
    }
}

/// One ray of the pose tests: the loss sum_i <gh_i, h(o + t_i d)> + <g_sh, SH(d)>, with fixed edges.
struct RayCase {
    origin: [f64; 3],
    dir: [f64; 3],
    edges: Vec<f64>,
    gh: Vec<f64>,
    gsh: [f64; sh::SH_DIM],
}

const NEAR: f64 = 0.05;
const FAR: f64 = 1000.0;

impl RayCase {
    fn random(r: &mut ChaCha8Rng, n: usize) -> Self {
        let mut edges: Vec<f64> = (0..=n).map(|_| r.random_range(0.0..1.0f64)).collect();
        edges.sort_by(f64::total_cmp);
        Self {
            origin: [0, 1, 2].map(|_| r.random_range(-0.9..0.9f64)),
            dir: unit(r),
            edges,
            gh: (0..3 * n).map(|_| r.random_range(-1.0..1.0f64)).collect(),
            gsh: std::array::from_fn(|_| r.random_range(-1.0..1.0f64)),
        }
    }

    fn loss(&self, o: [f64; 3], d: [f64; 3], contraction: bool) -> f64 {
        let mut l = 0.0;
        for i in 0..self.edges.len() - 1 {
            let tm = 0.5 * (edge_to_t(self.edges[i], NEAR, FAR) + edge_to_t(self.edges[i + 1], NEAR, FAR));
            let h = hash_input([0, 1, 2].map(|k| o[k] + tm * d[k]), contraction).0;
            l += dot(h, [self.gh[3 * i], self.gh[3 * i + 1], self.gh[3 * i + 2]]);
        }
        l + sh::encode(d).iter().zip(&self.gsh).map(|(a, b)| a * b).sum::<f64>()
    }
}

#[test]
fn ray_and_camera_gradients_match_finite_differences_of_the_corrected_ray() {
    // The whole chain: p = [t, w] -> corrected ray -> sample points -> hash inputs and SH(direction).
    let mut r = rng(4);
    for (i, w) in rotation_vectors(&mut r).into_iter().enumerate() {
        let case = RayCase::random(&mut r, 7);
        let contraction = i % 3 != 2;
        let t = [0, 1, 2].map(|_| r.random_range(-0.05..0.05f64));
        let p = [t[0], t[1], t[2], w[0], w[1], w[2]];
        let (o, d) = tw::apply(&p, case.origin, case.dir);
        let (g_o, g_d) = tw::ray_grad(o, d, &case.edges, (NEAR, FAR, contraction), &case.gh, Some(&case.gsh));
        let an = tw::camera_grad(w, case.dir, g_o, g_d);
        let f = |p: [f64; 6]| {
            let (o, d) = tw::apply(&p, case.origin, case.dir);
            case.loss(o, d, contraction)
        };
        for k in 0..6 {
            check_fd(an[k], fd(f, p, k), &format!("dL/dp[{k}] with |w| = {:.3}", dot(w, w).sqrt()));
        }
    }
}

#[test]
fn regulariser_matches_finite_differences() {
    let mut r = rng(5);
    let mut poses: Vec<f64> = (0..18).map(|_| r.random_range(-0.1..0.1f64)).collect();
    poses[6..9].copy_from_slice(&[0.0; 3]); // a camera with no translation: the subgradient 0
    let (losses, grads) = tw::regularizer(&poses, 4, 0.01, 0.001);
    assert_eq!(grads[6..9], [0.0; 3]);
    let total = |p: &[f64]| tw::regularizer(p, 4, 0.01, 0.001).0.iter().sum::<f64>();
    assert!((losses.iter().sum::<f64>() - total(&poses)).abs() < 1e-15);
    for k in (0..18).filter(|k| !(6..9).contains(k)) {
        let (mut a, mut b) = (poses.clone(), poses.clone());
        a[k] += 1e-6;
        b[k] -= 1e-6;
        check_fd(grads[k], (total(&a) - total(&b)) / 2e-6, &format!("dR/dp[{k}]"));
    }
}

fn to32<const N: usize>(v: [f64; N]) -> [f32; N] {
    v.map(|x| x as f32)
}

/// A parameter array holding the pose slot at `offset` (other entries 0.25, to see that they are left alone).
fn pose_array(g: &Context, name: &str, offset: usize, poses: &[f32]) -> LargeArray<f32> {
    let a = LargeArray::<f32>::new(g, name, offset + poses.len() + 8, MemoryCategory::Parameters).expect(name);
    let mut v = vec![0.25f32; offset + poses.len() + 8];
    v[offset..offset + poses.len()].copy_from_slice(poses);
    a.upload(g, 0, &v).expect("upload");
    a
}

fn random_poses(r: &mut ChaCha8Rng, cams: usize) -> Vec<f32> {
    let ws = rotation_vectors(r);
    (0..cams)
        .flat_map(|c| {
            let w = ws[c % ws.len()];
            [r.random_range(-0.05..0.05f64), r.random_range(-0.05..0.05), r.random_range(-0.05..0.05), w[0], w[1], w[2]]
        })
        .map(|v| v as f32)
        .collect()
}

#[test]
fn pose_kernels_match_their_twins() {
    let g = gpu();
    let k = PoseKernels::new(&g).expect("kernels");
    let mut r = rng(6);
    let (nr, cams, offset, n) = (53, 6, 40, 41);
    let poses = random_poses(&mut r, cams);
    let params = pose_array(&g, "params", offset, &poses);
    let grads = pose_array(&g, "grads", offset, &vec![0.5; poses.len()]);
    let slot = PoseSlot { params: &params, grads: &grads, offset };
    let cam: Vec<u32> = (0..nr).map(|i| (i * 7 % cams) as u32).collect();
    let cases: Vec<RayCase> = (0..nr).map(|_| RayCase::random(&mut r, n)).collect();
    let flat = |f: &dyn Fn(&RayCase) -> Vec<f64>| -> Vec<f32> { cases.iter().flat_map(f).map(|v| v as f32).collect() };
    let origins = up(&g, "origins", &flat(&|c| c.origin.to_vec()));
    let dirs = up(&g, "dirs", &flat(&|c| c.dir.to_vec()));
    let raw_dirs = up(&g, "raw dirs", &vec![0.0; 3 * nr]);
    let camb = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &cam).expect("cams");
    let rays = RayBuffers { origins: &origins, dirs: &dirs, n_rays: nr, ray_offset: 0 };

    // pose_apply
    let mut rec = g.recorder("pose apply").expect("rec");
    k.apply(&mut rec, slot, &camb, rays, &raw_dirs).expect("apply");
    rec.submit_and_wait().expect("submit");
    let (go, gd) = (g.download(&origins).expect("o"), g.download(&dirs).expect("d"));
    check_vals(
        &g.download(&raw_dirs).expect("raw"),
        &flat(&|c| c.dir.to_vec()).iter().map(|&v| v as f64).collect::<Vec<_>>(),
        "uncorrected dirs",
    );
    let mut want_o = Vec::new();
    let mut want_d = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let p: Vec<f32> = poses[6 * cam[i] as usize..6 * cam[i] as usize + 6].to_vec();
        let (o, d) = tw::apply(&p, to32(c.origin), to32(c.dir));
        want_o.extend(o.map(|v| v as f64));
        want_d.extend(d.map(|v| v as f64));
    }
    check_vals(&go, &want_o, "corrected origins");
    check_vals(&gd, &want_d, "corrected directions");

    // pose_ray_grad over two levels (the second with the SH term), with and without contraction.
    let stride = 20;
    let cdx: Vec<f32> = (0..nr * n * stride).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let cdx_b = up(&g, "colour dx", &cdx);
    let dummy = up(&g, "dummy", &[0.0; 4]);
    let edges = up(&g, "edges", &flat(&|c| c.edges.clone()));
    let mut dpos_v = flat(&|c| c.gh.clone());
    dpos_v[3..6].copy_from_slice(&[0.0; 3]); // an all-zero sample is skipped by the kernel; the result must not change
    let dpos = up(&g, "dpos", &dpos_v);
    let ray_grads = up(&g, "ray grads", &vec![0.0; 6 * nr]);
    // nerfacto's SH degree 4 (16 columns) with contraction; degree 2 (4 columns: the rest are zero in the forward,
    // so their input gradient must not reach the direction) without.
    // Both kernels: one invocation per ray, and 32 lanes per ray (two blocks of samples: n = 41).
    for (contraction, sh_count, lanes) in [(true, 16, false), (false, 4, false), (true, 16, true), (false, 4, true)] {
        let k = PoseKernels::with_ray_lanes(&g, lanes).expect("kernels");
        let geo = Geometry { near: NEAR as f32, far: FAR as f32, contraction };
        let mut rec = g.recorder("pose ray grad").expect("rec");
        let first = LevelGrad { n, edges: &edges, dpos: &dpos, colour_dx: None, sh_count, accumulate: false };
        k.ray_grad(&mut rec, rays, geo, &first, &dummy, &ray_grads).expect("level 0");
        let colour_dx = Some((&cdx_b, stride));
        let second = LevelGrad { n, edges: &edges, dpos: &dpos, colour_dx, sh_count, accumulate: true };
        k.ray_grad(&mut rec, rays, geo, &second, &dummy, &ray_grads).expect("level 1");
        rec.submit_and_wait().expect("submit");
        let got = g.download(&ray_grads).expect("ray grads");
        let mut want = Vec::new();
        for i in 0..nr {
            let e: Vec<f32> = cases[i].edges.iter().map(|&v| v as f32).collect();
            let dp = &dpos_v[3 * n * i..3 * n * (i + 1)];
            let mut dsh = [0.0f32; sh::SH_DIM];
            for s in 0..n {
                for (kk, v) in dsh.iter_mut().enumerate().take(sh_count) {
                    *v += cdx[(i * n + s) * stride + kk];
                }
            }
            let o = [go[3 * i], go[3 * i + 1], go[3 * i + 2]];
            let d = [gd[3 * i], gd[3 * i + 1], gd[3 * i + 2]];
            let nf = (NEAR as f32, FAR as f32, contraction);
            let (a_o, a_d) = tw::ray_grad(o, d, &e, nf, dp, None);
            let (b_o, b_d) = tw::ray_grad(o, d, &e, nf, dp, Some(&dsh));
            want.extend(a_o.iter().zip(&b_o).map(|(a, b)| (a + b) as f64));
            want.extend(a_d.iter().zip(&b_d).map(|(a, b)| (a + b) as f64));
        }
        let what = format!("per-ray gradients (contraction {contraction}, {sh_count} SH columns, lanes {lanes})");
        check_grad(&got, &want, &what);
    }

    // pose_reduce: every ray's share into its camera's 6 gradients (on top of 0.5).
    let rg: Vec<f32> = g.download(&ray_grads).expect("ray grads");
    let mut rec = g.recorder("pose reduce").expect("rec");
    k.reduce(&mut rec, slot, (&ray_grads, &raw_dirs, &camb), nr).expect("reduce");
    rec.submit_and_wait().expect("submit");
    let got = grads.download(&g).expect("grads");
    let mut want = vec![0.5f64; 6 * cams];
    for i in 0..nr {
        let c = cam[i] as usize;
        let w = [poses[6 * c + 3], poses[6 * c + 4], poses[6 * c + 5]];
        let gg = tw::camera_grad(
            w,
            to32(cases[i].dir),
            [rg[6 * i], rg[6 * i + 1], rg[6 * i + 2]],
            [rg[6 * i + 3], rg[6 * i + 4], rg[6 * i + 5]],
        );
        for (j, v) in gg.iter().enumerate() {
            want[6 * c + j] += *v as f64;
        }
    }
    check_grad(&got[offset..offset + 6 * cams], &want, "camera gradients");
    assert!(got[..offset].iter().chain(&got[offset + 6 * cams..]).all(|&v| v == 0.25), "outside the slot untouched");

    // pose_regularizer: adds its gradient, writes per-camera losses (mean over 4 "training" cameras). Fresh
    // gradients: the regulariser's share (~1e-4) would drown in the rays' sums of 41 samples.
    let losses = up(&g, "losses", &vec![0.0; cams]);
    let grads = pose_array(&g, "grads", offset, &vec![0.5; poses.len()]);
    let slot = PoseSlot { params: &params, grads: &grads, offset };
    let before = grads.download(&g).expect("grads");
    let mut rec = g.recorder("pose regulariser").expect("rec");
    k.regularizer(&mut rec, slot, (cams, 4), (0.01, 0.001), &losses).expect("regulariser");
    rec.submit_and_wait().expect("submit");
    let after = grads.download(&g).expect("grads");
    let (want_l, want_g) = tw::regularizer(&poses, 4, 0.01f32, 0.001f32);
    check_vals(&g.download(&losses).expect("losses"), &want_l.iter().map(|&v| v as f64).collect::<Vec<_>>(), "losses");
    let added: Vec<f32> = (0..6 * cams).map(|i| after[offset + i] - before[offset + i]).collect();
    check_grad(&added, &want_g.iter().map(|&v| v as f64).collect::<Vec<_>>(), "regulariser gradients");
}

#[test]
fn reference_step_pose_gradient_matches_finite_differences_of_its_loss() {
    // The whole CPU reference step (fields, compositing, MSE + distortion + regulariser) differentiated with respect to
    // every camera correction, against central differences of its total loss. Without proposal levels the sample
    // edges do not depend on the poses (with them, PDF resampling moves the edges, which the backward treats as
    // constants, as nerfstudio does), so the two must agree.
    use msnerf::nerf::config::{CameraOptMode, ModelConfig};
    use msnerf::nerf::model::{Model, POSE_SLOT};
    use msnerf::reference::pipeline::{train_step, RefRay};
    let g = gpu();
    let mut cfg = ModelConfig::resolve("tiny").expect("tiny");
    cfg.proposals.clear();
    cfg.field.grid.n_levels = 4;
    cfg.field.grid.log2_hashmap_size = 10;
    cfg.field.grid.max_resolution = 64;
    cfg.sampling.num_nerf_samples = 6;
    cfg.camera_optimizer.mode = CameraOptMode::SO3xR3;
    let cams = 3;
    let model = Model::new(&g, &cfg, 4, cams).expect("model");
    let mut r = rng(8);
    let mut params: Vec<f64> = model.store.params().download(&g).expect("params").iter().map(|&v| v as f64).collect();
    let grid = model.store.slot("field.grid").expect("grid").clone();
    for v in &mut params[grid.range()] {
        *v = r.random_range(-2.0..2.0);
    }
    let pose = model.store.slot(POSE_SLOT).expect("pose slot").clone();
    let poses = random_poses(&mut r, cams);
    for (i, v) in poses.iter().enumerate() {
        params[pose.offset + i] = *v as f64;
    }
    let rays: Vec<RefRay> = (0..12)
        .map(|i| RefRay {
            origin: [0, 1, 2].map(|_| r.random_range(-0.5..0.5)),
            dir: unit(&mut r),
            camera: i % cams,
            target: (0..4).map(|_| r.random_range(0.0..1.0)).collect(),
            weight: 1.0,
            depth: None,
        })
        .collect();
    let step = 7;
    let want = train_step(&model, &params, &rays, step, false);
    let total = |p: &[f64]| {
        let s = train_step(&model, p, &rays, step, false);
        s.loss_rgb + s.loss_distortion + s.loss_interlevel + s.loss_pose
    };
    for i in pose.range() {
        let (mut a, mut b) = (params.clone(), params.clone());
        a[i] += 1e-6;
        b[i] -= 1e-6;
        let fd = (total(&a) - total(&b)) / 2e-6;
        let an = want.grads[i];
        assert!((an - fd).abs() <= 1e-5 * (1.0 + an.abs()), "dL/dpose[{}]: analytic {an} vs fd {fd}", i - pose.offset);
    }
}
