//! Stability of the colour head and the optimiser: 128 bands end to end (colour MLP forward -> composite with loss ->
//! composite backward -> colour MLP backward), a sigmoid saturated to exactly 0 and 1, huge MLP inputs, and Adam with
//! epsilon 1e-15 fed zero, vanishing and huge gradients, and a learning rate of 0. GPU against the f64 twins
//! (`reference::mlp`, `reference::render`, `reference::adam`).
//! Tolerances: forward |a-b| <= 1e-5 + 1e-4|b|; per-sample gradients |a-b| <= 1e-4 (|b| + max|b|) + 1e-7; weight
//! gradients (sums over the batch) |a-b| <= 1e-4 (|b| + mean|b| of the matrix); Adam parameters 1e-5 + 1e-4|b|.

use crate::common;
use crate::stability_support;
use common::{gpu, rng};
use msnerf::gpu::{Context, LargeArray, MemoryCategory};
use msnerf::nerf::buffers::RAY_OUT_FIXED;
use msnerf::nerf::kernels::Geometry;
use msnerf::nn::adam::{self, AdamHyper};
use msnerf::nn::mlp::{Activation, Mlp, MlpConfig, MlpTrainBuffers};
use msnerf::nn::params::{ParamGroup, ParamStore, ParamStoreDesc, SlotDesc, SlotKind};
use msnerf::nn::{ParamSlice, RowSlice};
use msnerf::reference::adam::{adam_step, AdamScalars};
use msnerf::reference::mlp as mtw;
use msnerf::reference::render as tw;
use rand::Rng;
use stability_support::*;

/// nerfacto's colour head for B bands: [SH 16 | geo 15] (+ one 1.0 padding column) -> 64 -> 64 -> B, sigmoid.
fn colour_head(bands: usize) -> MlpConfig {
    MlpConfig {
        n_input: 31,
        n_output: bands,
        width: 64,
        n_hidden_layers: 2,
        output_activation: Activation::Sigmoid,
        half_activations: false,
    }
}

fn xavier(c: &MlpConfig, seed: u64, out_gain: f32) -> Vec<f32> {
    let mut r = rng(seed);
    let mats = c.matrices();
    let mut w = Vec::new();
    for (m, (rows, cols)) in mats.iter().enumerate() {
        let a = (6.0 / (rows + cols) as f32).sqrt() * if m + 1 == mats.len() { out_gain } else { 1.0 };
        w.extend((0..rows * cols).map(|_| r.random_range(-a..a)));
    }
    w
}

struct HeadRun {
    colours: Vec<f32>,
    grads: Vec<f32>,
    dx: Vec<f32>,
    comp: CompositeOut,
}

/// Colour MLP forward, composite (training) and both backward passes on the GPU.
fn run_head(g: &Context, r: &Render, c: &MlpConfig, w: &[f32], x: &[f32], case: &CompositeCase) -> HeadRun {
    let n = case.nr() * case.n;
    let mlp = Mlp::new(g, c).expect("mlp");
    let params = LargeArray::<f32>::new(g, "params", w.len(), MemoryCategory::Parameters).expect("params");
    params.upload(g, 0, w).expect("upload");
    let grads = LargeArray::<f32>::new(g, "grads", w.len(), MemoryCategory::Gradients).expect("grads");
    let input = up(g, "x", x);
    let out = zeros(g, "colours", n * c.n_output);
    let acts = zeros(g, "acts", c.hidden_floats(n));
    let p = ParamSlice { array: &params, offset: 0 };
    let xin = RowSlice { buf: &input, stride: c.in_pad(), col: 0 };
    let y = RowSlice { buf: &out, stride: c.n_output, col: 0 };
    let mut rec = g.recorder("head fwd").expect("rec");
    for ch in grads.chunks() {
        msnerf::ops::fill(&mut rec, ch, 0.0f32, 0, ch.len()).expect("zero");
    }
    mlp.forward(&mut rec, p, xin, n, y, &acts).expect("forward");
    rec.submit_and_wait().expect("submit");
    let colours = g.download(&out).expect("colours");
    // The composite sees the MLP's colours.
    let comp_case = CompositeCase { colours: colours.clone(), ..clone_case(case) };
    let comp = r.composite(&comp_case, true);
    let dy = up(g, "dy colour", &comp.d_colour);
    let deltas = zeros(g, "deltas", c.delta_floats(n));
    let scratch = zeros(g, "scratch", mlp.wgrad_scratch_floats(n));
    let dx = zeros(g, "dx", n * c.in_pad());
    let bufs = MlpTrainBuffers { acts: &acts, deltas: &deltas, scratch: &scratch };
    let mut rec = g.recorder("head bwd").expect("rec");
    let gs = ParamSlice { array: &grads, offset: 0 };
    let dys = RowSlice { buf: &dy, stride: c.n_output, col: 0 };
    let dxs = RowSlice { buf: &dx, stride: c.in_pad(), col: 0 };
    mlp.backward(&mut rec, p, gs, (xin, y, dys), n, &bufs, Some(dxs)).expect("backward");
    rec.submit_and_wait().expect("submit");
    HeadRun { colours, grads: grads.download(g).expect("grads"), dx: g.download(&dx).expect("dx"), comp }
}

fn clone_case(c: &CompositeCase) -> CompositeCase {
    CompositeCase {
        rays: c.rays.clone(),
        n: c.n,
        bands: c.bands,
        edges: c.edges.clone(),
        raw: c.raw.clone(),
        colours: c.colours.clone(),
        targets: c.targets.clone(),
        band_w: c.band_w.clone(),
        background: c.background,
        geo: c.geo,
        scale: c.scale,
    }
}

/// The same chain in f64: colour MLP twin -> composite twin -> colour MLP twin backward.
fn check_head(c: &MlpConfig, w: &[f32], x: &[f32], case: &CompositeCase, got: &HeadRun, what: &str) {
    let (nr, n, bb) = (case.nr(), case.n, case.bands);
    assert_finite(&got.colours, &format!("{what}: colours"));
    assert_finite(&got.comp.ray_out, &format!("{what}: ray outputs"));
    assert_finite(&got.comp.d_raw, &format!("{what}: dL/draw"));
    assert_finite(&got.comp.d_colour, &format!("{what}: dL/dc"));
    assert_finite(&got.grads, &format!("{what}: weight gradients"));
    assert_finite(&got.dx, &format!("{what}: dL/dx"));
    let w64 = f64s(w);
    let rows: Vec<Vec<f64>> = (0..nr * n).map(|s| f64s(&x[s * c.in_pad()..(s + 1) * c.in_pad()])).collect();
    let colours: Vec<f64> = rows.iter().flat_map(|row| mtw::forward(c, &w64, row).1).collect();
    check_vals(&got.colours, &colours, &format!("{what}: colour MLP output"));
    let mut want_g = vec![0.0f64; w.len()];
    for i in 0..nr {
        let t = tw::composite(&tw::CompositeIn {
            geom: case.rays.geom64(i, case.geo),
            edges: &f64s(&case.edges[i * (n + 1)..(i + 1) * (n + 1)]),
            raw: &f64s(&case.raw[i * n..(i + 1) * n]),
            colours: &colours[i * n * bb..(i + 1) * n * bb],
            target: &f64s(&case.targets[i * (bb + 1)..i * (bb + 1) + bb]),
            ray_weight: case.targets[i * (bb + 1) + bb] as f64,
            band_weights: &f64s(&case.band_w),
            density_scale: case.scale as f64,
            background: tw::Background::LastSample,
            rgb_norm: case.rgb_norm() as f64,
            dist_norm: case.dist_norm() as f64,
            grad_scaling: false,
            depth: None,
        });
        let ro = &got.comp.ray_out[i * (RAY_OUT_FIXED + bb)..(i + 1) * (RAY_OUT_FIXED + bb)];
        check_vals(&ro[..3], &[t.loss_rgb, t.loss_dist, t.accumulation], &format!("{what}: ray {i} losses"));
        check_vals(&ro[RAY_OUT_FIXED..], &t.colour, &format!("{what}: ray {i} composite colour"));
        check_grad(&got.comp.d_raw[i * n..(i + 1) * n], &t.d_raw, &format!("{what}: ray {i} dL/draw"));
        check_grad(&got.comp.d_colour[i * n * bb..(i + 1) * n * bb], &t.d_colour, &format!("{what}: ray {i} dL/dc"));
        for k in 0..n {
            let s = i * n + k;
            let dx = mtw::backward(c, &w64, &rows[s], &t.d_colour[k * bb..(k + 1) * bb], &mut want_g);
            check_grad(&got.dx[s * c.in_pad()..(s + 1) * c.in_pad()], &dx, &format!("{what}: sample {s} dL/dx"));
        }
    }
    let mut off = 0;
    for (m, (rows, cols)) in c.matrices().into_iter().enumerate() {
        let want = &want_g[off..off + rows * cols];
        let mean = want.iter().map(|v| v.abs()).sum::<f64>() / want.len() as f64;
        for (e, &b) in want.iter().enumerate() {
            let a = got.grads[off + e] as f64;
            assert!((a - b).abs() <= 1e-4 * (b.abs() + mean) + 1e-12, "{what}: matrix {m} element {e}: {a} vs {b}");
        }
        off += rows * cols;
    }
}

fn head_case(nr: usize, n: usize, bands: usize, seed: u64) -> (CompositeCase, Vec<f32>) {
    let mut r = rng(seed);
    let rays = Rays::same(nr, [0.1, 0.0, 0.2], [0.0, 0.6, -0.8]);
    let edges: Vec<f32> = (0..nr).flat_map(|_| uniform_edges(n)).collect();
    let raw = (0..nr * n).map(|_| r.random_range(-1.0f32..5.0)).collect();
    let mut targets = Vec::new();
    for _ in 0..nr {
        // targets span the whole range, outside (0, 1) too
        targets.extend((0..bands).map(|b| [0.0, 1.0, -0.1, 1.1, 0.3][b % 5]));
        targets.push(1.0);
    }
    let case = CompositeCase {
        rays,
        n,
        bands,
        edges,
        raw,
        colours: vec![],
        targets,
        band_w: (0..bands).map(|b| 0.5 + (b % 3) as f32 * 0.25).collect(),
        background: None,
        geo: Geometry { near: 0.05, far: 1000.0, contraction: true },
        scale: 0.01,
    };
    let c = colour_head(bands);
    let x: Vec<f32> = (0..nr * n)
        .flat_map(|_| {
            let mut row: Vec<f32> = (0..31).map(|_| r.random_range(-1.0f32..1.0)).collect();
            row.resize(c.in_pad(), 1.0);
            row
        })
        .collect();
    (case, x)
}

/// 128 bands end to end. What breaks without the guards: the composite keeps per-band accumulators in a fixed array
/// of MAX_BANDS = 128 (more would overrun it; `CompositeParams` callers are bounded by the model's band limit), and
/// the colour head's 128 outputs span 8 padded 16-column tiles.
#[test]
fn one_hundred_twenty_eight_bands_end_to_end() {
    let g = gpu();
    let r = Render::new(&g);
    let bands = 128;
    let c = colour_head(bands);
    let (case, x) = head_case(3, 6, bands, 1);
    let w = xavier(&c, 2, 1.0);
    let got = run_head(&g, &r, &c, &w, &x, &case);
    check_head(&c, &w, &x, &case, &got, "128 bands");
}

/// A sigmoid saturated to exactly 0 and 1 (pre-activations of +-100s: exp(100) overflows to Inf, 1/(1+Inf) = 0) and
/// huge inputs (geometric features of 1e4 from a diverging density MLP). Nothing divides by y(1-y), so a saturated
/// head gives zero (not NaN) gradients; the composite's loss and backward are polynomial in the colour.
#[test]
fn saturated_sigmoid_and_huge_inputs_stay_finite() {
    let g = gpu();
    let r = Render::new(&g);
    let bands = 6;
    let c = colour_head(bands);
    let (case, mut x) = head_case(4, 5, bands, 3);
    let w = xavier(&c, 4, 400.0); // last layer x 400: pre-activations of several hundred
    let got = run_head(&g, &r, &c, &w, &x, &case);
    let saturated = got.colours.iter().filter(|&&v| v == 0.0 || v == 1.0).count();
    assert!(saturated * 2 > got.colours.len(), "most outputs saturate exactly: {saturated} of {}", got.colours.len());
    check_head(&c, &w, &x, &case, &got, "saturated sigmoid");
    for (i, v) in x.iter_mut().enumerate() {
        if (16..31).contains(&(i % c.in_pad())) {
            *v *= 1e4;
        }
    }
    let w = xavier(&c, 5, 1.0);
    let got = run_head(&g, &r, &c, &w, &x, &case);
    check_head(&c, &w, &x, &case, &got, "huge inputs");
}

fn adam_store(g: &Context, lr: f64, len: usize) -> ParamStore {
    let mut grp = ParamGroup::new("fields", lr, lr, 0);
    grp.adam = AdamHyper { beta1: 0.9, beta2: 0.999, eps: 1e-15, weight_decay: 0.0 };
    let desc = ParamStoreDesc {
        name: "adam stability",
        groups: vec![grp],
        slots: vec![SlotDesc::new("w", SlotKind::Zeros { len }, "fields")],
        seed: 1,
        chunk_shift: None,
    };
    ParamStore::new(g, &desc).expect("store")
}

/// Adam with epsilon 1e-15 (not representable in fp16: the state is fp32) over 40 steps of zero, vanishing (1e-30,
/// whose square underflows fp32), ordinary and huge (1e19, whose square 1e38 is just below fp32's max) gradients, and
/// zero gradients again (momentum decays, nothing divides 0 by 0: sqrt(v)/bc2 + eps > 0 always). Against the f64
/// twin at |a-b| <= 1e-5 + 1e-4|b| (the f32 twin follows the kernel bit for bit; flush-to-zero of v below 1e-38 only
/// matters where eps dominates). Learning rate 0: the group is not stepped, parameters and moments stay bitwise.
#[test]
fn adam_eps_1e15_zero_vanishing_and_huge_gradients_and_zero_lr() {
    let g = gpu();
    let len = 6;
    let schedule: Vec<[f32; 6]> = (0..40)
        .map(|t| match t {
            0..=9 => [0.0; 6],
            10..=19 => [1e-30, -1e-30, 1e-20, 0.0, 1e-38, -1e-10],
            20..=29 => [0.5, -2.0, 1e3, 1e19, -1e19, 1e-3],
            _ => [0.0; 6],
        })
        .collect();
    let h = AdamHyper { beta1: 0.9, beta2: 0.999, eps: 1e-15, weight_decay: 0.0 };
    let mut s = adam_store(&g, 1e-2, len);
    let slot = s.slot("w").expect("slot").clone();
    let init = [0.5f32, -0.5, 1.0, 0.0, 2.0, -3.0];
    s.upload_slot(s.params(), &slot, &init).expect("init");
    let (mut p, mut m, mut v) = (f64s(&init), vec![0.0f64; len], vec![0.0f64; len]);
    for (t, gr) in schedule.iter().enumerate() {
        s.upload_slot(s.grads(), &slot, gr).expect("grads");
        let mut rec = g.recorder("adam").expect("rec");
        adam::step(&mut rec, &mut s, &[true], 1.0).expect("step");
        rec.submit_and_wait().expect("submit");
        adam_step(&mut p, &f64s(gr), &mut m, &mut v, &AdamScalars::new(&h, 1e-2, t as u64 + 1, 1.0));
        let (gp, gm, gv) = (
            s.download_slot(s.params(), &slot).expect("p"),
            s.download_slot(s.m(), &slot).expect("m"),
            s.download_slot(s.v(), &slot).expect("v"),
        );
        assert_finite(&gp, &format!("step {t}: params"));
        assert_finite(&gm, &format!("step {t}: m"));
        assert_finite(&gv, &format!("step {t}: v"));
        check_vals(&gp, &p, &format!("step {t}: params"));
        check_vals(&gm, &m, &format!("step {t}: m"));
        check_vals(&gv, &v, &format!("step {t}: v"));
        if t < 10 {
            assert_eq!(gp, init, "zero gradients from a zero state move nothing");
        }
    }
    // lr 0: not stepped at all.
    let mut s = adam_store(&g, 0.0, len);
    let slot = s.slot("w").expect("slot").clone();
    s.upload_slot(s.params(), &slot, &init).expect("init");
    for gr in &schedule[10..30] {
        s.upload_slot(s.grads(), &slot, gr).expect("grads");
        let mut rec = g.recorder("adam").expect("rec");
        let rep = adam::step(&mut rec, &mut s, &[true], 1.0).expect("step");
        rec.submit_and_wait().expect("submit");
        assert!(!rep[0].stepped && rep[0].t == 0, "{rep:?}");
    }
    assert_eq!(s.download_slot(s.params(), &slot).expect("p"), init);
    assert!(s.download_slot(s.m(), &slot).expect("m").iter().all(|&x| x == 0.0));
    assert!(s.download_slot(s.v(), &slot).expect("v").iter().all(|&x| x == 0.0));
}
