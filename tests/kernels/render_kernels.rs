//! Render kernels against their CPU twins (`msnerf::reference::render`, `msnerf::data::camera`) and the backward
//! passes against central finite differences of the f64 twin.
//! Tolerances: element-wise |a-b| <= 1e-5 + 1e-4|b| for forward values; gradients (sums with cancellation)
//! |a-b| <= 1e-4 (|b| + max|b| of the array) + 1e-7. Kernels and twin use different exp/pow implementations.

use crate::common;
use common::{gpu, rng};
use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::gpu::{Context, GpuBuffer, MemoryCategory};
use msnerf::nerf::buffers::{RayOut, RAY_OUT_FIXED};
use msnerf::nerf::config::DepthLoss;
use msnerf::nerf::kernels::{
    CompositeBuffers, CompositeParams, Geometry, InterlevelBuffers, Jitter, RayBuffers, RenderKernels,
};
use msnerf::nerf::rays::GpuCamera;
use msnerf::reference::render as tw;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

fn up(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Activations, data).expect("upload")
}

fn zeros(g: &Context, name: &str, n: usize) -> GpuBuffer<f32> {
    up(g, name, &vec![0.0; n])
}

fn check_grad(got: &[f32], want: &[f64], what: &str) {
    let scale = want.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for i in 0..got.len() {
        let (a, b) = (got[i] as f64, want[i]);
        assert!((a - b).abs() <= 1e-4 * (b.abs() + scale) + 1e-7, "{what}[{i}]: got {a} want {b} (scale {scale})");
    }
}

fn check_vals(got: &[f32], want: &[f64], what: &str) {
    for i in 0..got.len() {
        assert!(common::close(got[i] as f64, want[i], 1e-5, 1e-4), "{what}[{i}]: got {} want {}", got[i], want[i]);
    }
}

struct Rays {
    o: Vec<[f32; 3]>,
    d: Vec<[f32; 3]>,
}

fn random_rays(r: &mut ChaCha8Rng, n: usize) -> Rays {
    let o = (0..n).map(|_| [0, 1, 2].map(|_| r.random_range(-0.8f32..0.8))).collect();
    let d = (0..n)
        .map(|_| {
            let v: [f32; 3] = [0, 1, 2].map(|_| r.random_range(-1.0f32..1.0));
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
            v.map(|x| x / l)
        })
        .collect();
    Rays { o, d }
}

fn geom64(rays: &Rays, i: usize, geo: Geometry) -> tw::RayGeom<f64> {
    tw::RayGeom {
        origin: rays.o[i].map(|v| v as f64),
        dir: rays.d[i].map(|v| v as f64),
        near: geo.near as f64,
        far: geo.far as f64,
        contraction: geo.contraction,
    }
}

fn geom32(rays: &Rays, i: usize, geo: Geometry) -> tw::RayGeom<f32> {
    tw::RayGeom { origin: rays.o[i], dir: rays.d[i], near: geo.near, far: geo.far, contraction: geo.contraction }
}

#[test]
fn ray_gen_matches_the_camera_model() {
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    let cams = [
        Camera {
            model: CameraModel::Pinhole,
            fx: 300.0,
            fy: 310.0,
            cx: 160.0,
            cy: 120.0,
            width: 320,
            height: 240,
            distortion: Distortion::default(),
        },
        Camera {
            model: CameraModel::OpenCv,
            fx: 280.0,
            fy: 280.0,
            cx: 161.0,
            cy: 119.0,
            width: 320,
            height: 240,
            distortion: Distortion { k1: -0.12, k2: 0.03, k3: 0.0, k4: 0.0, p1: 0.001, p2: -0.002 },
        },
        Camera {
            model: CameraModel::OpenCvFisheye,
            fx: 200.0,
            fy: 200.0,
            cx: 160.0,
            cy: 120.0,
            width: 320,
            height: 240,
            distortion: Distortion { k1: 0.05, ..Default::default() },
        },
        // Parallel rays (the survey exports' camera): 0.01 units per pixel.
        Camera {
            model: CameraModel::Orthographic,
            fx: 100.0,
            fy: 100.0,
            cx: 160.0,
            cy: 120.0,
            width: 320,
            height: 240,
            distortion: Distortion::default(),
        },
    ];
    let nc = cams.len();
    let c2w: [[f32; 4]; 3] = [[0.0, -0.6, 0.8, 0.3], [1.0, 0.0, 0.0, -0.2], [0.0, 0.8, 0.6, 0.5]];
    let table: Vec<GpuCamera> = cams.iter().map(|c| GpuCamera::new(c, &c2w)).collect();
    let mut r = rng(1);
    let n = 301;
    let pixels: Vec<u32> =
        (0..n).flat_map(|i| [(i % nc) as u32, r.random_range(0..240), r.random_range(0..320)]).collect();
    let cam_buf = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &table).expect("cams");
    let pix = GpuBuffer::from_slice(&g, "pixels", MemoryCategory::Rays, &pixels).expect("pixels");
    let (o, d, norms) = (zeros(&g, "o", 3 * n), zeros(&g, "d", 3 * n), zeros(&g, "norms", n));
    let mut rec = g.recorder("rays").expect("rec");
    k.ray_gen(&mut rec, &cam_buf, &pix, RayBuffers { origins: &o, dirs: &d, n_rays: n, ray_offset: 0 }, &norms)
        .expect("ray_gen");
    rec.submit_and_wait().expect("submit");
    let (go, gd, gn) = (g.download(&o).expect("o"), g.download(&d).expect("d"), g.download(&norms).expect("n"));
    for i in 0..n {
        let want = cams[i % nc].ray_f32(&c2w, pixels[3 * i + 1], pixels[3 * i + 2]);
        if cams[i % nc].model == CameraModel::Orthographic {
            // Independently, in f64 from the definition: origin = t + R (x, -y, 0), direction = R (0, 0, -1).
            let (v, u) = (pixels[3 * i + 1] as f64 + 0.5, pixels[3 * i + 2] as f64 + 0.5);
            let (x, y) = ((u - 160.0) / 100.0, -(v - 120.0) / 100.0);
            for a in 0..3 {
                let m = c2w[a].map(|e| e as f64);
                let o = m[3] + m[0] * x + m[1] * y;
                assert!(
                    (go[3 * i + a] as f64 - o).abs() < 1e-5,
                    "ortho ray {i} origin axis {a}: {} vs {o}",
                    go[3 * i + a]
                );
                assert!((gd[3 * i + a] as f64 + m[2]).abs() < 1e-6, "ortho ray {i} direction axis {a}");
            }
        }
        for a in 0..3 {
            // One rounding apart at most (the orthographic origin is a sum the GPU may fuse).
            assert!(
                (go[3 * i + a] - want.origin[a]).abs() <= 2e-6 * (1.0 + want.origin[a].abs()),
                "ray {i} origin axis {a}: {} vs {}",
                go[3 * i + a],
                want.origin[a]
            );
            assert!(
                (gd[3 * i + a] - want.direction[a]).abs() < 2e-5,
                "ray {i} axis {a}: {} vs {}",
                gd[3 * i + a],
                want.direction[a]
            );
        }
        assert!(common::close_f32(gn[i], want.direction_norm));
    }
}

/// The per-ray kernels' GPU variants are the default on GPUs and off on CPU devices, where they measured 3-10x
/// slower (docs/benchmarks.md); `MSNERF_RAY_LANES` overrides both.
#[test]
fn ray_lanes_default_follows_the_device_kind() {
    let g = gpu();
    let want = match std::env::var("MSNERF_RAY_LANES").as_deref() {
        Ok("1") => true,
        Ok("0") => false,
        Ok(v) => panic!("MSNERF_RAY_LANES={v} is not 0 or 1"),
        Err(_) => !g.caps().is_cpu && g.caps().subgroup_arithmetic,
    };
    assert_eq!(msnerf::nerf::kernels::default_ray_lanes(&g).expect("default"), want);
    assert_eq!(RenderKernels::new(&g).expect("kernels").ray_lanes(), want);
}

/// Draws a batch, runs the sampling kernels of two levels, and checks them against the twin: with the serial
/// per-ray weights and resampling and with their lanes variants (32 invocations per ray; on lavapipe four subgroups
/// of 8, so the shared-memory combination of subgroup scans runs too), for a level of one block of 32 samples and
/// one of three blocks, the last partial.
#[test]
fn sampling_weights_and_resampling_match_twin() {
    let g = gpu();
    assert!(g.caps().subgroup_arithmetic, "the lanes kernels must be tested: the device lacks subgroup arithmetic");
    for lanes in [false, true] {
        let k = RenderKernels::with_ray_lanes(&g, lanes).expect("kernels");
        assert_eq!(k.ray_lanes(), lanes);
        for (n0, n1) in [(32, 12), (75, 40)] {
            sampling_case(&g, &k, n0, n1);
        }
    }
    // Past pdf_resample_lanes' 1024 bins the serial resampler runs, with the lanes weights before it.
    let k = RenderKernels::with_ray_lanes(&g, true).expect("kernels");
    sampling_case(&g, &k, msnerf::nerf::kernels::PDF_LANES_MAX_BINS + 76, 16);
}

fn sampling_case(g: &Context, k: &RenderKernels, n0: usize, n1: usize) {
    let mut r = rng(2);
    let nr = 67;
    let rays = random_rays(&mut r, nr);
    for contraction in [true, false] {
        let geo = Geometry { near: 0.05, far: 1000.0, contraction };
        let o = up(g, "o", &rays.o.concat());
        let d = up(g, "d", &rays.d.concat());
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 1000 };
        let (e0, p0) = (zeros(g, "e0", nr * (n0 + 1)), zeros(g, "p0", nr * n0 * 3));
        let raw: Vec<f32> = (0..nr * n0).map(|_| r.random_range(-4.0f32..3.0)).collect();
        let raw_b = up(g, "raw", &raw);
        let w0 = zeros(g, "w0", nr * n0);
        let (e1, p1) = (zeros(g, "e1", nr * (n1 + 1)), zeros(g, "p1", nr * n1 * 3));
        let jit = |level| Jitter { seed: 7, step: 3, level, enabled: true };
        let mut rec = g.recorder("sampling").expect("rec");
        k.sample_initial(&mut rec, rb, geo, n0, jit(0), (&e0, &p0)).expect("sample");
        k.weights(&mut rec, rb, geo, n0, &e0, (&raw_b, 1), 0.01, &w0).expect("weights");
        k.pdf_resample(&mut rec, rb, geo, (n0, n1), 0.6, jit(1), (&e0, &w0), (&e1, &p1)).expect("pdf");
        rec.submit_and_wait().expect("submit");
        let (ge0, gp0, gw0, ge1, gp1) = (
            g.download(&e0).expect("e0"),
            g.download(&p0).expect("p0"),
            g.download(&w0).expect("w0"),
            g.download(&e1).expect("e1"),
            g.download(&p1).expect("p1"),
        );
        for i in 0..nr {
            let gm = geom32(&rays, i, geo);
            let u0 = tw::ray_uniform(7, 3, 1000 + i as u32, 0);
            let edges = tw::initial_edges(n0, u0, true);
            common::assert_all_close_f32(&ge0[i * (n0 + 1)..(i + 1) * (n0 + 1)], &edges, "initial edges");
            let pos: Vec<f32> = gm.positions(&edges).concat();
            common::assert_all_close_f32(&gp0[i * n0 * 3..(i + 1) * n0 * 3], &pos, "initial positions");
            let w = tw::weights(&gm, &edges, &raw[i * n0..(i + 1) * n0], 0.01);
            common::assert_all_close_f32(&gw0[i * n0..(i + 1) * n0], &w, "weights");
            let u1 = tw::ray_uniform(7, 3, 1000 + i as u32, 1);
            // Resample from the GPU's own weights so the comparison isolates the resampler.
            let e_new = tw::pdf_resample(&edges, &gw0[i * n0..(i + 1) * n0], n1, 0.6, u1, true);
            common::assert_all_close_f32(&ge1[i * (n1 + 1)..(i + 1) * (n1 + 1)], &e_new, "resampled edges");
            assert!(e_new.windows(2).all(|w| w[0] <= w[1]), "resampled edges are sorted");
            let pos1: Vec<f32> = gm.positions(&e_new).concat();
            common::assert_all_close_f32(&gp1[i * n1 * 3..(i + 1) * n1 * 3], &pos1, "resampled positions");
        }
        // The hash inputs lie in the unit cube (contracted), or are zero outside the box.
        assert!(gp0.iter().all(|&v| (0.0..=1.0).contains(&v)));
    }
}

#[test]
fn resampling_concentrates_samples_where_the_weight_is() {
    // One heavy bin: most new edges fall inside it; with anneal 0 the bins count equally (uniform in s).
    let edges: Vec<f64> = (0..=10).map(|k| k as f64 / 10.0).collect();
    let mut w = vec![0.0; 10];
    w[6] = 1.0;
    let e = tw::pdf_resample(&edges, &w, 20, 1.0, 0.5, false);
    let inside = e.iter().filter(|&&v| (0.6..=0.7).contains(&v)).count();
    assert!(inside >= 18, "{inside} of 21 edges in the heavy bin: {e:?}");
    let flat = tw::pdf_resample(&edges, &w, 9, 0.0, 0.5, false);
    for (k, v) in flat.iter().enumerate() {
        assert!((v - (k as f64 + 0.5) / 10.0).abs() < 1e-12, "anneal 0 gives the bin-uniform cdf");
    }
}

struct CompositeCase {
    nr: usize,
    n: usize,
    bands: usize,
    rays: Rays,
    edges: Vec<f32>,
    raw: Vec<f32>,
    colours: Vec<f32>,
    targets: Vec<f32>,
    band_w: Vec<f32>,
    /// Per ray (target distance, sigma): every fifth ray has none (distance 0).
    depth: Vec<f32>,
}

fn composite_case(r: &mut ChaCha8Rng, nr: usize, n: usize, bands: usize) -> CompositeCase {
    let rays = random_rays(r, nr);
    let mut edges = Vec::new();
    for _ in 0..nr {
        let mut e: Vec<f32> = (0..=n).map(|_| r.random_range(0.0f32..1.0)).collect();
        e.sort_by(f32::total_cmp);
        edges.extend(e);
    }
    let raw = (0..nr * n).map(|_| r.random_range(-2.0f32..6.0)).collect();
    let colours = (0..nr * n * bands).map(|_| r.random_range(0.05f32..0.95)).collect();
    let mut targets = Vec::new();
    for i in 0..nr {
        // Every fifth ray is a rig ray (rig-aware training): it observed band i % B only, the others are NaN.
        let observed = |b: usize| i % 5 != 1 || b == i % bands;
        targets.extend((0..bands).map(|b| {
            let y = r.random_range(0.0f32..1.0);
            if observed(b) {
                y
            } else {
                f32::NAN
            }
        }));
        targets.push(if i % 7 == 3 { 0.0 } else { 1.0 }); // some rays masked out
    }
    let band_w = (0..bands).map(|b| 0.5 + b as f32 * 0.25).collect();
    let mut depth = Vec::new();
    for i in 0..nr {
        // Targets spread over the sampled range (t of edges in [0, 1] covers near .. far), sigmas from a fraction of
        // an interval to several, so both the URF window and its line-of-sight part are exercised.
        let d = if i % 5 == 2 { 0.0 } else { r.random_range(0.1f32..3.0) };
        depth.extend([d, r.random_range(0.05f32..0.8)]);
    }
    CompositeCase { nr, n, bands, rays, edges, raw, colours, targets, band_w, depth }
}

#[allow(clippy::too_many_arguments)]
fn composite_in<'a>(
    cc: &'a CompositeCase,
    i: usize,
    raw: &'a [f64],
    colours: &'a [f64],
    target: &'a [f64],
    band_w: &'a [f64],
    edges: &'a [f64],
    geo: Geometry,
    bg: tw::Background,
) -> tw::CompositeIn<'a, f64> {
    tw::CompositeIn {
        geom: geom64(&cc.rays, i, geo),
        edges,
        raw,
        colours,
        target,
        ray_weight: cc.targets[i * (cc.bands + 1) + cc.bands] as f64,
        band_weights: band_w,
        density_scale: 0.01,
        background: bg,
        rgb_norm: 1.0 / (cc.nr * cc.bands) as f64,
        dist_norm: 0.002 / cc.nr as f64,
        grad_scaling: false,
        depth: None,
    }
}

/// Ray `i`'s depth target of `cc` under `loss` (None: off), with the norm the GPU case uses.
fn depth_in(cc: &CompositeCase, i: usize, loss: Option<DepthLoss>) -> Option<tw::DepthTarget<f64>> {
    loss.map(|loss| tw::DepthTarget {
        loss,
        distance: cc.depth[2 * i] as f64,
        sigma: cc.depth[2 * i + 1] as f64,
        norm: DEPTH_NORM as f64,
    })
}

/// The depth-loss weight of the composite tests (a large one, so the term is visible next to the colour loss).
const DEPTH_NORM: f32 = 0.05;

#[test]
fn composite_matches_twin_for_every_background() {
    let g = gpu();
    // The serial kernel, the lanes variant within one block of samples and over two (45 samples), and past the
    // variant's 256 samples, where the serial kernel runs.
    let past = msnerf::nerf::kernels::COMPOSITE_LANES_MAX_SAMPLES + 44;
    for (lanes, n) in [(false, 24), (true, 24), (true, 45), (true, past)] {
        let k = RenderKernels::with_ray_lanes(&g, lanes).expect("kernels");
        composite_twin_case(&g, &k, n);
    }
}

fn composite_twin_case(g: &Context, k: &RenderKernels, n: usize) {
    let mut r = rng(3);
    let cc = composite_case(&mut r, 53, n, 6);
    let (nr, n, bb) = (cc.nr, cc.n, cc.bands);
    use msnerf::nerf::kernels::BackgroundMode;
    let random = BackgroundMode::Random { seed: 7, step: 3 };
    let cases = [
        (tw::Background::LastSample, BackgroundMode::LastSample, false, None),
        (tw::Background::Constant(1.0), BackgroundMode::Constant(1.0), false, None),
        (tw::Background::LastSample, BackgroundMode::LastSample, true, None),
        (tw::Background::Random { seed: 7, step: 3, ray: 0 }, random, false, None),
        (tw::Background::LastSample, BackgroundMode::LastSample, false, Some(DepthLoss::DsNerf)),
        (tw::Background::Constant(0.5), BackgroundMode::Constant(0.5), false, Some(DepthLoss::Urf)),
    ];
    for (bg, bgv, gs, depth_loss) in cases {
        let (mut with_loss, mut with_target) = (0usize, 0usize);
        let geo = Geometry { near: 0.05, far: 1000.0, contraction: true };
        let o = up(g, "o", &cc.rays.o.concat());
        let d = up(g, "d", &cc.rays.d.concat());
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
        let stride = 16;
        let mut density = vec![0.0f32; nr * n * stride];
        for s in 0..nr * n {
            density[s * stride] = cc.raw[s];
        }
        let bufs_edges = up(g, "edges", &cc.edges);
        let dens = up(g, "density", &density);
        let cols = up(g, "colours", &cc.colours);
        let tg = up(g, "targets", &cc.targets);
        let bw = up(g, "band weights", &cc.band_w);
        let dyd = zeros(g, "dy density", nr * n * stride);
        let dyc = zeros(g, "dy colour", nr * n * bb);
        let wts = zeros(g, "weights", nr * n);
        let out = zeros(g, "ray out", nr * (RAY_OUT_FIXED + bb));
        let p = CompositeParams {
            bands: bb,
            density_stride: stride,
            density_scale: 0.01,
            background: bgv,
            rgb_norm: 1.0 / (nr * bb) as f32,
            dist_norm: 0.002 / nr as f32,
            grad_scaling: gs,
            train: true,
            depth: depth_loss.map(|l| (l, DEPTH_NORM)),
        };
        let dt = up(g, "depth targets", &cc.depth);
        let bufs = CompositeBuffers {
            edges: &bufs_edges,
            density: &dens,
            colours: &cols,
            targets: &tg,
            band_weights: &bw,
            dy_density: &dyd,
            dy_colour: &dyc,
            weights: &wts,
            ray_out: &out,
            depth_targets: depth_loss.map(|_| &dt),
        };
        let mut rec = g.recorder("composite").expect("rec");
        k.composite(&mut rec, rb, geo, n, &p, &bufs).expect("composite");
        rec.submit_and_wait().expect("submit");
        let (gd, gc, gw, go) = (
            g.download(&dyd).expect("dyd"),
            g.download(&dyc).expect("dyc"),
            g.download(&wts).expect("w"),
            g.download(&out).expect("out"),
        );
        let bw64: Vec<f64> = cc.band_w.iter().map(|&v| v as f64).collect();
        for i in 0..nr {
            let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
            let (raw, colours) = (f(&cc.raw[i * n..(i + 1) * n]), f(&cc.colours[i * n * bb..(i + 1) * n * bb]));
            let (target, edges) =
                (f(&cc.targets[i * (bb + 1)..i * (bb + 1) + bb]), f(&cc.edges[i * (n + 1)..(i + 1) * (n + 1)]));
            // A random background differs per ray: the twin draws it from the same stream (ray offset 0).
            let bg = if let tw::Background::Random { seed, step, .. } = bg {
                tw::Background::Random { seed, step, ray: i as u32 }
            } else {
                bg
            };
            let mut ci = composite_in(&cc, i, &raw, &colours, &target, &bw64, &edges, geo, bg);
            ci.grad_scaling = gs;
            ci.depth = depth_in(&cc, i, depth_loss);
            let t = tw::composite(&ci);
            if gs {
                // Gradient scaling only damps: never larger than without it, and strictly smaller near the camera.
                ci.grad_scaling = false;
                let plain = tw::composite(&ci);
                assert!(t.d_raw.iter().zip(&plain.d_raw).all(|(a, b)| a.abs() <= b.abs() + 1e-15));
            }
            check_vals(&gw[i * n..(i + 1) * n], &t.weights, "weights");
            let ro = &go[i * (RAY_OUT_FIXED + bb)..(i + 1) * (RAY_OUT_FIXED + bb)];
            use RayOut::*;
            let cols =
                [LossRgb, LossDistortion, Accumulation, MedianDepth, ExpectedDepth, DepthQ25, DepthQ75, LossDepth];
            check_vals(
                &cols.map(|c| c.of(ro)),
                &[
                    t.loss_rgb,
                    t.loss_dist,
                    t.accumulation,
                    t.median_depth,
                    t.expected_depth,
                    t.depth_q25,
                    t.depth_q75,
                    t.loss_depth,
                ],
                "ray outputs",
            );
            // A ray without a target (or masked out) has no depth loss; most rays with one have some (a URF target
            // behind every sample, or a Gaussian far from all of them, legitimately gives 0).
            let has = depth_loss.is_some() && cc.depth[2 * i] > 0.0 && cc.targets[i * (bb + 1) + bb] > 0.0;
            if !has {
                assert_eq!(RayOut::LossDepth.of(ro), 0.0, "ray {i}: no target, no depth loss");
            }
            with_loss += usize::from(has && t.loss_depth != 0.0);
            with_target += usize::from(has);
            check_vals(&ro[RAY_OUT_FIXED..], &t.colour, "colour");
            // A rig ray's loss, from eq. 3.1 in plain f64 on the GPU's own colours: the observed band alone; the
            // unobserved bands get no colour gradient at all.
            if i % 5 == 1 {
                let (b, y) = (i % bb, cc.targets[i * (bb + 1) + i % bb] as f64);
                let e = ro[RAY_OUT_FIXED + b] as f64 - y;
                let w = cc.targets[i * (bb + 1) + bb] as f64;
                let want = cc.band_w[b] as f64 * e * e * w / (nr * bb) as f64;
                let got = RayOut::LossRgb.of(ro) as f64;
                assert!((got - want).abs() <= 1e-4 * want.abs() + 1e-9, "ray {i}: rig loss {got} vs {want}");
                for s in 0..n {
                    for ob in (0..bb).filter(|&ob| ob != b) {
                        assert_eq!(gc[(i * n + s) * bb + ob], 0.0, "ray {i}: unobserved band {ob} has a gradient");
                    }
                }
            }
            let draw: Vec<f32> = (0..n).map(|s| gd[(i * n + s) * stride]).collect();
            check_grad(&draw, &t.d_raw, "dL/draw");
            check_grad(&gc[i * n * bb..(i + 1) * n * bb], &t.d_colour, "dL/dc");
        }
        assert!(
            5 * with_loss >= 4 * with_target,
            "{depth_loss:?}: {with_loss} of {with_target} rays with a target have a depth loss"
        );
    }
}

#[test]
fn composite_backward_matches_finite_differences() {
    let mut r = rng(4);
    let cc = composite_case(&mut r, 6, 10, 4);
    let (n, bb) = (cc.n, cc.bands);
    let bw64: Vec<f64> = cc.band_w.iter().map(|&v| v as f64).collect();
    let modes = [
        (tw::Background::LastSample, None),
        (tw::Background::Constant(0.3), None),
        (tw::Background::LastSample, Some(DepthLoss::DsNerf)),
        (tw::Background::Constant(0.3), Some(DepthLoss::Urf)),
    ];
    for (bg, depth_loss) in modes {
        for contraction in [true, false] {
            let geo = Geometry { near: 0.05, far: 1000.0, contraction };
            for i in 0..cc.nr {
                let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
                let (raw, colours) = (f(&cc.raw[i * n..(i + 1) * n]), f(&cc.colours[i * n * bb..(i + 1) * n * bb]));
                let (target, edges) =
                    (f(&cc.targets[i * (bb + 1)..i * (bb + 1) + bb]), f(&cc.edges[i * (n + 1)..(i + 1) * (n + 1)]));
                let with_depth = |mut ci: tw::CompositeIn<'_, f64>| {
                    ci.depth = depth_in(&cc, i, depth_loss);
                    tw::composite(&ci)
                };
                let loss = |raw: &[f64], col: &[f64]| {
                    let t = with_depth(composite_in(&cc, i, raw, col, &target, &bw64, &edges, geo, bg));
                    t.loss_rgb + t.loss_dist + t.loss_depth
                };
                let t = with_depth(composite_in(&cc, i, &raw, &colours, &target, &bw64, &edges, geo, bg));
                let h = 1e-6;
                // A central difference of a loss L carries rounding of ~1e-16 |L| / h: the absolute tolerance scales
                // with the loss (the URF window term alone reaches tens here).
                let abs_tol = 1e-9 * (1.0 + (t.loss_rgb + t.loss_dist + t.loss_depth).abs());
                for k in 0..n {
                    let (mut a, mut b) = (raw.clone(), raw.clone());
                    a[k] += h;
                    b[k] -= h;
                    let fd = (loss(&a, &colours) - loss(&b, &colours)) / (2.0 * h);
                    assert!(
                        common::close(t.d_raw[k], fd, abs_tol, 1e-5),
                        "{bg:?} {depth_loss:?} ray {i} raw {k}: {} vs {fd}",
                        t.d_raw[k]
                    );
                }
                for k in 0..n * bb {
                    let (mut a, mut b) = (colours.clone(), colours.clone());
                    a[k] += h;
                    b[k] -= h;
                    let fd = (loss(&raw, &a) - loss(&raw, &b)) / (2.0 * h);
                    assert!(
                        common::close(t.d_colour[k], fd, abs_tol, 1e-5),
                        "{bg:?} {depth_loss:?} ray {i} colour {k}: {} vs {fd}",
                        t.d_colour[k]
                    );
                }
            }
        }
    }
}

/// The depth losses against nerfstudio's formulas (`model_components/losses.py`), written here in plain f64 from the
/// weights, midpoints and interval lengths, with this project's scale-free normalisation (docs/geometry.md):
/// `ds_nerf_depth_loss` (its `sigma` a variance, ours squared) divided by sigma sqrt(2 pi), and
/// `urban_radiance_field_depth_loss` with the Gaussian window's density times the interval length and without its
/// (d - predicted depth)^2 term (nerfstudio's predicted depth is the median, which passes no gradient).
#[test]
fn depth_losses_match_nerfstudio_formulas() {
    let mut r = rng(14);
    let cc = composite_case(&mut r, 40, 32, 3);
    let (n, bb) = (cc.n, cc.bands);
    let geo = Geometry { near: 0.05, far: 1000.0, contraction: true };
    let bw64: Vec<f64> = cc.band_w.iter().map(|&v| v as f64).collect();
    let mut checked = [0usize; 2];
    for i in 0..cc.nr {
        let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let (raw, colours) = (f(&cc.raw[i * n..(i + 1) * n]), f(&cc.colours[i * n * bb..(i + 1) * n * bb]));
        let (target, edges) =
            (f(&cc.targets[i * (bb + 1)..i * (bb + 1) + bb]), f(&cc.edges[i * (n + 1)..(i + 1) * (n + 1)]));
        let ray_w = cc.targets[i * (bb + 1) + bb] as f64;
        let (d, sd) = (cc.depth[2 * i] as f64, cc.depth[2 * i + 1] as f64);
        if d <= 0.0 || ray_w == 0.0 {
            continue;
        }
        let g = geom64(&cc.rays, i, geo);
        let t: Vec<f64> = edges.iter().map(|&e| g.t(e)).collect();
        for (li, loss) in [DepthLoss::DsNerf, DepthLoss::Urf].into_iter().enumerate() {
            let mut ci = composite_in(&cc, i, &raw, &colours, &target, &bw64, &edges, geo, tw::Background::LastSample);
            ci.depth = Some(tw::DepthTarget { loss, distance: d, sigma: sd, norm: 1.0 });
            let out = tw::composite(&ci);
            let w = &out.weights;
            let steps: Vec<f64> = (0..n).map(|k| 0.5 * (t[k] + t[k + 1])).collect();
            let lengths: Vec<f64> = (0..n).map(|k| t[k + 1] - t[k]).collect();
            let want = match loss {
                DepthLoss::DsNerf => {
                    let sigma_ns = sd * sd;
                    (0..n)
                        .map(|k| {
                            -(w[k] + 1e-7).ln() * (-(steps[k] - d).powi(2) / (2.0 * sigma_ns)).exp() * lengths[k]
                                / (sd * (2.0 * std::f64::consts::PI).sqrt())
                        })
                        .sum::<f64>()
                }
                DepthLoss::Urf => {
                    let std = sd / 3.0;
                    let pdf =
                        |x: f64| (-(x * x) / (2.0 * std * std)).exp() / (std * (2.0 * std::f64::consts::PI).sqrt());
                    let mut l = 0.0;
                    for k in 0..n {
                        if steps[k] <= d + sd && steps[k] >= d - sd {
                            l += (w[k] - pdf(steps[k] - d) * lengths[k]).powi(2);
                        }
                        if steps[k] < d - sd {
                            l += w[k] * w[k];
                        }
                    }
                    l
                }
            };
            assert!(
                common::close(out.loss_depth, want * ray_w, 1e-12, 1e-10),
                "{loss:?} ray {i}: {} vs {want}",
                out.loss_depth
            );
            checked[li] += 1;
        }
    }
    assert!(checked.iter().all(|&c| c > 20), "enough rays with targets: {checked:?}");
}

#[test]
fn interlevel_matches_twin_and_finite_differences() {
    let g = gpu();
    // The serial kernel and the lanes variant (its searches and prefix sums over blocks of 32: two blocks of NeRF
    // intervals, three of proposal samples in the second case).
    for lanes in [false, true] {
        let k = RenderKernels::with_ray_lanes(&g, lanes).expect("kernels");
        for (n_nerf, n_prop) in [(9, 20), (45, 70)] {
            interlevel_case(&g, &k, n_nerf, n_prop);
        }
    }
    // Past interlevel_lanes' 256 NeRF samples the serial kernel runs.
    let k = RenderKernels::with_ray_lanes(&g, true).expect("kernels");
    interlevel_case(&g, &k, msnerf::nerf::kernels::INTERLEVEL_LANES_MAX.0 + 44, 40);
}

fn interlevel_case(g: &Context, k: &RenderKernels, n_nerf: usize, n_prop: usize) {
    let mut r = rng(5);
    let nr = 41;
    let rays = random_rays(&mut r, nr);
    let geo = Geometry { near: 0.05, far: 1000.0, contraction: true };
    let sorted = |r: &mut ChaCha8Rng, n: usize| {
        let mut e: Vec<f32> = (0..=n).map(|_| r.random_range(0.0f32..1.0)).collect();
        e.sort_by(f32::total_cmp);
        e
    };
    let ne: Vec<f32> = (0..nr).flat_map(|_| sorted(&mut r, n_nerf)).collect();
    let pe: Vec<f32> = (0..nr).flat_map(|_| sorted(&mut r, n_prop)).collect();
    let nw: Vec<f32> = (0..nr * n_nerf).map(|_| r.random_range(0.0f32..0.3)).collect();
    let praw: Vec<f32> = (0..nr * n_prop).map(|_| r.random_range(-3.0f32..5.0)).collect();
    let o = up(g, "o", &rays.o.concat());
    let d = up(g, "d", &rays.d.concat());
    let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
    let (neb, nwb, peb, prb) = (up(g, "ne", &ne), up(g, "nw", &nw), up(g, "pe", &pe), up(g, "praw", &praw));
    let pw = zeros(g, "pw", nr * n_prop);
    let dy = zeros(g, "dy", nr * n_prop);
    let losses = zeros(g, "losses", nr);
    let norm = 1.0 / (nr * n_nerf) as f32;
    let mut rec = g.recorder("interlevel").expect("rec");
    k.weights(&mut rec, rb, geo, n_prop, &peb, (&prb, 1), 0.01, &pw).expect("weights");
    let bufs = InterlevelBuffers {
        nerf_edges: &neb,
        nerf_weights: &nwb,
        prop_edges: &peb,
        prop_raw: &prb,
        prop_weights: &pw,
        prop_dy: &dy,
        losses: &losses,
    };
    k.interlevel(&mut rec, rb, geo, (n_nerf, n_prop), 1, 0.01, norm, &bufs).expect("interlevel");
    rec.submit_and_wait().expect("submit");
    let (gl, gdy) = (g.download(&losses).expect("losses"), g.download(&dy).expect("dy"));
    let mut any_grad = false;
    for i in 0..nr {
        let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let gm = geom64(&rays, i, geo);
        let (nei, nwi) = (f(&ne[i * (n_nerf + 1)..(i + 1) * (n_nerf + 1)]), f(&nw[i * n_nerf..(i + 1) * n_nerf]));
        let (pei, pri) = (f(&pe[i * (n_prop + 1)..(i + 1) * (n_prop + 1)]), f(&praw[i * n_prop..(i + 1) * n_prop]));
        let (loss, grad) = tw::interlevel(&gm, &nei, &nwi, &pei, &pri, 0.01, norm as f64);
        assert!(common::close(gl[i] as f64, loss, 1e-7, 1e-4), "ray {i} loss {} vs {loss}", gl[i]);
        check_grad(&gdy[i * n_prop..(i + 1) * n_prop], &grad, "interlevel dL/draw");
        any_grad |= grad.iter().any(|&v| v != 0.0);
        for k in 0..n_prop {
            let h = 1e-6;
            let (mut a, mut b) = (pri.clone(), pri.clone());
            a[k] += h;
            b[k] -= h;
            let fd = (tw::interlevel(&gm, &nei, &nwi, &pei, &a, 0.01, norm as f64).0
                - tw::interlevel(&gm, &nei, &nwi, &pei, &b, 0.01, norm as f64).0)
                / (2.0 * h);
            assert!(common::close(grad[k], fd, 1e-9, 1e-4), "ray {i} prop raw {k}: {} vs {fd}", grad[k]);
        }
    }
    assert!(any_grad, "the case must exercise the loss");
}

#[test]
fn colour_input_and_column_copy_match_twin() {
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    let mut r = rng(6);
    let (nr, n, geo_dim, app_dim, in_pad, ds) = (19, 5, 15, 4, 48, 16);
    let rays = random_rays(&mut r, nr);
    let density: Vec<f32> = (0..nr * n * ds).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let emb: Vec<f32> = (0..3 * app_dim).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let cams: Vec<u32> = (0..nr).map(|i| (i % 3) as u32).collect();
    let o = up(&g, "o", &rays.o.concat());
    let d = up(&g, "d", &rays.d.concat());
    let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
    let (dens, embb) = (up(&g, "density", &density), up(&g, "emb", &emb));
    let camb = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &cams).expect("cams");
    let rows = zeros(&g, "rows", nr * n * in_pad);
    let rows_fixed = zeros(&g, "rows fixed", nr * n * in_pad);
    let rows_deg2 = zeros(&g, "rows degree 2", nr * n * in_pad);
    let copied = up(&g, "copied", &vec![-7.0; nr * n * 20]);
    let mut rec = g.recorder("colour input").expect("rec");
    k.colour_input(
        &mut rec,
        rb,
        n,
        (&dens, ds),
        geo_dim,
        16,
        Some((embb.binding(), &camb, app_dim, None)),
        (&rows, in_pad),
    )
    .expect("ci");
    k.colour_input(
        &mut rec,
        rb,
        n,
        (&dens, ds),
        geo_dim,
        16,
        Some((embb.binding(), &camb, app_dim, Some(2))),
        (&rows_fixed, in_pad),
    )
    .expect("ci");
    // SH degree 2 (field.direction_sh_degree): the first 4 SH columns, zeros in the other 12.
    k.colour_input(
        &mut rec,
        rb,
        n,
        (&dens, ds),
        geo_dim,
        4,
        Some((embb.binding(), &camb, app_dim, None)),
        (&rows_deg2, in_pad),
    )
    .expect("ci");
    k.copy_cols(&mut rec, nr * n, geo_dim, (&rows, in_pad, 16), (&copied, 20, 3)).expect("copy cols");
    rec.submit_and_wait().expect("submit");
    let (gr, gf, gc, g2) = (
        g.download(&rows).expect("rows"),
        g.download(&rows_fixed).expect("fixed"),
        g.download(&copied).expect("copied"),
        g.download(&rows_deg2).expect("rows degree 2"),
    );
    for s in 0..nr * n {
        let ray = s / n;
        let sh = msnerf::reference::sh::encode(rays.d[ray]);
        let mut want: Vec<f32> = sh.to_vec();
        want.extend_from_slice(&density[s * ds + 1..s * ds + 1 + geo_dim]);
        let mut fixed = want.clone();
        want.extend_from_slice(&emb[cams[ray] as usize * app_dim..(cams[ray] as usize + 1) * app_dim]);
        fixed.extend_from_slice(&emb[2 * app_dim..3 * app_dim]);
        want.resize(in_pad, 1.0);
        fixed.resize(in_pad, 1.0);
        common::assert_all_close_f32(&gr[s * in_pad..(s + 1) * in_pad], &want, "colour input row");
        common::assert_all_close_f32(&gf[s * in_pad..(s + 1) * in_pad], &fixed, "colour input row, fixed embedding");
        let mut deg2 = want.clone();
        deg2[4..16].fill(0.0);
        common::assert_all_close_f32(&g2[s * in_pad..(s + 1) * in_pad], &deg2, "colour input row, SH degree 2");
        let row = &gc[s * 20..(s + 1) * 20];
        assert!(row[..3].iter().chain(&row[3 + geo_dim..]).all(|&v| v == -7.0), "columns outside the copy untouched");
        common::assert_same(&row[3..3 + geo_dim], &gr[s * in_pad + 16..s * in_pad + 16 + geo_dim], "copied columns");
    }
}

#[test]
fn appearance_grad_matches_twin() {
    // CPU twin: grad_emb[cam[ray]][k] += dx[s][col + k] for every sample s of ray `ray` (fp32 atomics on the GPU,
    // in any order: compared within the fp32 tolerance of a sum).
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    let mut r = rng(7);
    let (nr, n, dim, stride, col, cams, offset) = (37, 5, 4, 24, 19, 3, 64);
    let mut dx: Vec<f32> = (0..nr * n * stride).map(|_| r.random_range(-1.0f32..1.0)).collect();
    for s in (0..nr * n).step_by(3) {
        dx[s * stride + col] = 0.0; // zero gradients are skipped by the kernel; the result must not change
    }
    let cam: Vec<u32> = (0..nr).map(|i| (i % cams) as u32).collect();
    let grads = msnerf::gpu::LargeArray::<f32>::new(&g, "grads", offset + cams * dim + 16, MemoryCategory::Gradients)
        .expect("grads");
    grads.upload(&g, 0, &vec![0.5; offset + cams * dim + 16]).expect("init");
    let dxb = up(&g, "dx", &dx);
    let camb = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &cam).expect("cams");
    let mut rec = g.recorder("appearance grad").expect("rec");
    k.appearance_grad(&mut rec, &grads, offset, (nr, n), dim, (&dxb, stride, col), &camb).expect("dispatch");
    rec.submit_and_wait().expect("submit");
    let got = grads.download(&g).expect("download");
    let mut want = vec![0.5f64; got.len()];
    for s in 0..nr * n {
        for d in 0..dim {
            want[offset + cam[s / n] as usize * dim + d] += dx[s * stride + col + d] as f64;
        }
    }
    check_vals(&got, &want, "appearance gradients (entries outside the slot stay 0.5)");
}
