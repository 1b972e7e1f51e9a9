//! Fused MLP kernels against the CPU twin (`msnerf::reference::mlp`) and finite differences.
//! Tolerances: forward, deltas and input gradients fp32 |a-b| <= 1e-5 + 1e-4|b|; weight gradients (sums over the
//! batch, where cancellation makes |b| small) |a-b| <= 1e-4 (|b| + mean|b| of the matrix). With fp16 hidden
//! activations (the twin rounds them as the kernels store them) every tolerance is 100x looser, and likewise for the
//! cooperative-matrix (tensor-core) kernels, whose operands are fp16 (11 significant bits) with fp32 sums.

use crate::common;
use common::{gpu, rng};
use msnerf::gpu::{BufferDesc, Context, GpuBuffer, LargeArray, MemoryCategory};
use msnerf::nn::mlp::{coop_available, Activation, Mlp, MlpConfig, MlpTiling, MlpTrainBuffers};
use msnerf::nn::{ParamSlice, RowSlice};
use msnerf::ops;
use msnerf::reference::mlp as twin;
use rand::Rng;

fn buf(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Activations, data).expect("upload")
}

fn zeros(g: &Context, name: &str, len: usize) -> GpuBuffer<f32> {
    buf(g, name, &vec![0.0; len])
}

/// Xavier-uniform weights, as the parameter store initialises them.
fn weights(c: &MlpConfig, seed: u64) -> Vec<f32> {
    let mut r = rng(seed);
    let mut w = Vec::new();
    for (rows, cols) in c.matrices() {
        let a = (6.0 / (rows + cols) as f32).sqrt();
        w.extend((0..rows * cols).map(|_| r.random_range(-a..a)));
    }
    w
}

/// Every kernel family on this device: its default, the other one (register tiles, shared-memory tiles) and, where
/// the default runs on cooperative matrices, the fp32 shared-memory tiles too.
fn check_config(g: &Context, c: &MlpConfig, n: usize, seed: u64) {
    let default = MlpTiling::for_device(g.caps()).expect("tiling");
    let fp32 = MlpTiling { coop_matrix: false, coop_layers: false, ..default };
    let register = MlpTiling { shared_tiles: false, ..fp32 };
    // The device's choice, the other kind of tiles, and the register tiles with rows read both ways (texel views
    // and storage reads).
    let mut tilings = vec![default, MlpTiling { shared_tiles: !default.shared_tiles, ..fp32 }];
    for texel_rows in [true, false] {
        tilings.push(MlpTiling { texel_rows, ..register });
    }
    if default.coop_matrix {
        tilings.push(fp32);
    }
    let mut done: Vec<MlpTiling> = Vec::new();
    for tiling in tilings {
        if !done.contains(&tiling) {
            // Input rows on whole texels and off them (the texel variants fall back to storage reads there; the
            // shared tiles read no texels).
            for aligned in [true, false].into_iter().filter(|&a| a || !tiling.shared_tiles) {
                check_with(g, c, n, seed, tiling, aligned);
            }
            done.push(tiling);
        }
    }
}

/// `check_config` with fp32 and with fp16 hidden activations.
fn check_both_precisions(g: &Context, c: &MlpConfig, n: usize, seed: u64) {
    check_config(g, c, n, seed);
    check_config(g, &MlpConfig { half_activations: true, ..c.clone() }, n, seed);
}

fn check_with(g: &Context, c: &MlpConfig, n: usize, seed: u64, tiling: MlpTiling, aligned: bool) {
    let mlp = Mlp::with_tiling(g, c, tiling).expect("mlp");
    let w = weights(c, seed);
    let offset = 40;
    let params = LargeArray::<f32>::new(g, "params", offset + w.len(), MemoryCategory::Parameters).expect("params");
    params.upload(g, offset, &w).expect("upload");
    let grads = LargeArray::<f32>::new(g, "grads", offset + w.len(), MemoryCategory::Gradients).expect("grads");
    let mut r = rng(seed + 1);
    // Input rows: in_pad columns inside a wider row (padding columns are real inputs too), starting on a whole
    // texel (column 4 of rows of a multiple of 4 floats) or not (column 2 of an odd width).
    let (in_stride, in_col) = if aligned { (c.in_pad() + 4, 4) } else { (c.in_pad() + 3, 2) };
    let x: Vec<f32> = (0..n * in_stride).map(|_| r.random_range(-1.0..1.0)).collect();
    let dy_host: Vec<f32> = (0..n * c.n_output).map(|_| r.random_range(-1.0..1.0)).collect();
    let (out_stride, out_col) = (c.n_output + 1, 1);
    let input = buf(g, "x", &x);
    let out = zeros(g, "y", n * out_stride);
    let out_infer = zeros(g, "y infer", n * out_stride);
    let dy = buf(g, "dy", &dy_host);
    let acts = zeros(g, "acts", c.hidden_floats(n));
    let deltas = zeros(g, "deltas", c.delta_floats(n));
    let scratch = zeros(g, "scratch", mlp.wgrad_scratch_floats(n));
    let dx = zeros(g, "dx", n * c.in_pad());
    let p = ParamSlice { array: &params, offset };
    let gs = ParamSlice { array: &grads, offset };
    let xin = RowSlice { buf: &input, stride: in_stride, col: in_col };
    let loose = if c.half_activations || tiling.coop_matrix || tiling.coop_layers { 100.0 } else { 1.0 };
    let close = |a: f32, b: f32| common::close(a as f64, b as f64, 1e-5 * loose, 1e-4 * loose);
    let y = RowSlice { buf: &out, stride: out_stride, col: out_col };
    let mut rec = g.recorder("mlp").expect("recorder");
    for ch in grads.chunks() {
        ops::fill(&mut rec, ch, 0.0f32, 0, ch.len()).expect("zero grads");
    }
    mlp.forward(&mut rec, p, xin, n, y, &acts).expect("forward");
    let infer_scratch = zeros(g, "infer scratch", c.infer_scratch_floats(n));
    let out_infer_slice = RowSlice { buf: &out_infer, stride: out_stride, col: out_col };
    mlp.infer(&mut rec, p, xin, n, out_infer_slice, &infer_scratch).expect("infer");
    let bufs = MlpTrainBuffers { acts: &acts, deltas: &deltas, scratch: &scratch };
    let dys = RowSlice { buf: &dy, stride: c.n_output, col: 0 };
    let dxs = RowSlice { buf: &dx, stride: c.in_pad(), col: 0 };
    mlp.backward(&mut rec, p, gs, (xin, y, dys), n, &bufs, Some(dxs)).expect("backward");
    let timing = rec.submit_and_wait().expect("submit");

    // Which layer kernels read their rows through texel views: all of them for fp32 rows on whole texels, none
    // where texel reads are off or the tiles are shared ones, some otherwise (the first layer's unaligned input
    // and fp16 activations fall back to storage reads; the input gradient's fp32 deltas keep the texels).
    let layers: u32 =
        timing.by_kernel().iter().filter(|k| k.name == "mlp_fwd" || k.name == "mlp_bwd").map(|k| k.count).sum();
    let texel = mlp.texel_dispatches() as u32;
    let why = format!("{c:?} {tiling:?} aligned {aligned}: {texel} of {layers} layer kernels read texels");
    if !tiling.texel_rows || tiling.shared_tiles {
        assert_eq!(texel, 0, "{why}");
    } else if aligned && !c.half_activations {
        assert_eq!(texel, layers, "{why}");
    } else {
        assert!(texel > 0 && texel < layers, "{why}");
    }

    let got_y = g.download(&out).expect("y");
    let got_infer = g.download(&out_infer).expect("y infer");
    let got_dx = g.download(&dx).expect("dx");
    let got_acts = stored_activations(c, &g.download(&acts).expect("acts"));
    let got_g = grads.download(g).expect("grads");
    let mut want_g = vec![0.0f64; w.len()];
    let w64: Vec<f64> = w.iter().map(|&v| v as f64).collect();
    for i in 0..n {
        let row: Vec<f64> =
            x[i * in_stride + in_col..i * in_stride + in_col + c.in_pad()].iter().map(|&v| v as f64).collect();
        let (hidden, yv) = twin::forward(c, &w64, &row);
        // The stored hidden activations themselves (fp16 ones decoded from pairs of halves).
        for (l, h) in hidden.iter().enumerate() {
            for (j, &want) in h.iter().enumerate() {
                let got = got_acts[(l * n + i) * c.width + j] as f64;
                if c.half_activations && l == 0 && !tiling.coop_layers {
                    // The first layer's inputs are exact, so the GPU's fp16 value and the twin's (its f64 sum
                    // rounded to nearest) are one fp16 step apart at most, plus the fp32 sum's own error (1e-6
                    // covers it where the sum cancels down to a small value, whose step is small too).
                    let step = half_step(want);
                    assert!(
                        (got - want).abs() <= step + 1e-6,
                        "{c:?} {tiling:?} hidden layer 0 row {i} unit {j}: got {got} want {want} (step {step})"
                    );
                }
                assert!(
                    close(got as f32, want as f32),
                    "{c:?} {tiling:?} hidden layer {l} row {i} unit {j}: got {got} want {want}"
                );
            }
        }
        for j in 0..c.n_output {
            let (gy, wy) = (got_y[i * out_stride + out_col + j], yv[j] as f32);
            assert!(close(gy, wy), "{c:?} {tiling:?} row {i} out {j}: got {gy} want {wy}");
        }
        assert_eq!(got_y[i * out_stride], 0.0, "column before the output slot untouched");
        let d: Vec<f64> = dy_host[i * c.n_output..(i + 1) * c.n_output].iter().map(|&v| v as f64).collect();
        // fp16 operands move a ReLU's input by about 1e-4: one that close to zero may be off on the GPU and on in
        // the twin, which changes the row's gradients by a whole unit's share. With cooperative matrices the twin's
        // backward therefore starts from the kernels' stored forward pass (its masks; each value was checked
        // against the twin's above).
        let dxv = if tiling.coop_layers {
            let (stored, ys) = stored_forward(c, (&got_acts, n), (&got_y, out_stride, out_col), i);
            twin::backward_from(c, &w64, &row, (&stored, &ys), &d, &mut want_g)
        } else {
            twin::backward(c, &w64, &row, &d, &mut want_g)
        };
        for k in 0..c.in_pad() {
            let (gd, wd) = (got_dx[i * c.in_pad() + k], dxv[k] as f32);
            assert!(close(gd, wd), "{c:?} {tiling:?} row {i} dx {k}: got {gd} want {wd}");
        }
    }
    common::assert_same(&got_infer, &got_y, "inference equals the training forward");
    let mut off = 0;
    for (m, (rows, cols)) in c.matrices().into_iter().enumerate() {
        let want = &want_g[off..off + rows * cols];
        let mean = want.iter().map(|v| v.abs()).sum::<f64>() / want.len() as f64;
        for e in 0..rows * cols {
            let (gv, wv) = (got_g[offset + off + e] as f64, want[e]);
            assert!(
                (gv - wv).abs() <= 1e-4 * loose * (wv.abs() + mean),
                "{c:?} {tiling:?} matrix {m} element {e}: got {gv} want {wv}"
            );
        }
        off += rows * cols;
    }
    assert!(got_g[..offset].iter().all(|&v| v == 0.0), "gradients outside the module untouched");
}

/// Row `i` of a stored forward pass of `n` rows: its hidden layers (from the activations as values) and its outputs
/// (`n_output` values at `col` of rows `stride` apart), as `twin::backward_from` takes them.
fn stored_forward(
    c: &MlpConfig,
    (acts, n): (&[f32], usize),
    (y, stride, col): (&[f32], usize, usize),
    i: usize,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let hidden = (0..c.n_hidden_layers)
        .map(|l| (0..c.width).map(|j| acts[(l * n + i) * c.width + j] as f64).collect())
        .collect();
    (hidden, (0..c.n_output).map(|j| y[i * stride + col + j] as f64).collect())
}

/// Distance from a non-negative fp16 value to the next one up.
fn half_step(v: f64) -> f64 {
    let h = half::f16::from_f64(v);
    half::f16::from_bits(h.to_bits() + 1).to_f64() - h.to_f64()
}

/// The activations buffer as values: floats, or pairs of fp16 packed in each float (low half first).
fn stored_activations(c: &MlpConfig, raw: &[f32]) -> Vec<f32> {
    if !c.half_activations {
        return raw.to_vec();
    }
    raw.iter()
        .flat_map(|v| {
            let b = v.to_bits();
            [b as u16, (b >> 16) as u16].map(|h| half::f16::from_bits(h).to_f32())
        })
        .collect()
}

fn cfg(n_input: usize, n_output: usize, width: usize, n_hidden_layers: usize, act: Activation) -> MlpConfig {
    MlpConfig { n_input, n_output, width, n_hidden_layers, output_activation: act, half_activations: false }
}

#[test]
fn nerfacto_density_and_proposal_shapes() {
    let g = gpu();
    check_config(&g, &cfg(32, 16, 64, 1, Activation::None), 1003, 1); // density MLP: grid 32 -> 64 -> 1 + 15 geo
    check_both_precisions(&g, &cfg(10, 1, 16, 1, Activation::None), 517, 2); // proposal MLP
}

#[test]
fn colour_head_for_six_bands() {
    let g = gpu();
    // SH 16 + geo 15 + appearance 32 = 63 inputs -> 64 -> 64 -> 6 bands, sigmoid.
    check_config(&g, &cfg(63, 6, 64, 2, Activation::Sigmoid), 777, 3);
}

#[test]
fn wide_network_with_128_bands_and_other_activations() {
    let g = gpu();
    check_config(&g, &cfg(32, 128, 128, 2, Activation::Sigmoid), 203, 4);
    // Multispectral-NeRF Table 1's colour head: 80 padded inputs (not a multiple of 32) -> 128 -> 128 -> 6.
    check_both_precisions(&g, &cfg(79, 6, 128, 2, Activation::Sigmoid), 211, 9);
    check_both_precisions(&g, &cfg(20, 3, 32, 3, Activation::Exponential), 301, 5);
    check_config(&g, &cfg(16, 17, 16, 1, Activation::Relu), 129, 6);
}

#[test]
fn weight_gradients_over_many_splits() {
    // 70001 rows: 274 splits of 256 rows for the register tiles; the shared-memory tiles cap the splits at 256 and
    // take 288 rows per split (244 splits, the last one short).
    check_both_precisions(&gpu(), &cfg(16, 3, 16, 1, Activation::None), 70_001, 12);
}

/// The tensor-core kernels (`mlp_coop_layer`, `mlp_coop_wgrad`) where this device and build have them: on by
/// default, and against the f64 twin on every shape family the profiles use (fp32 and fp16 activations, an output
/// layer narrower than a 16 x 16 fragment, deltas below 5e-7 that fp16 alone would flush, many splits). Elsewhere
/// (lavapipe, or a build without the `shaderc-from-source` feature) the test says so, checks that the fp32 tiles
/// are chosen and that asking for cooperative matrices is refused by name; `MSNERF_REQUIRE_COOPMAT=1` (the GPU
/// runs of docs/benchmarks.md) makes their absence a failure.
#[test]
fn cooperative_matrix_kernels_match_the_twin_or_are_refused() {
    let g = gpu();
    let default = MlpTiling::for_device(g.caps()).expect("tiling");
    let c = cfg(32, 16, 64, 1, Activation::None);
    check_tiny_deltas(&g, MlpTiling { coop_matrix: false, coop_layers: false, ..default }); // the check, on fp32
    if !coop_available(g.caps()) {
        let required = std::env::var("MSNERF_REQUIRE_COOPMAT").is_ok_and(|v| v == "1");
        assert!(!required, "MSNERF_REQUIRE_COOPMAT=1 but {} / this build has no cooperative matrices", g.caps().name);
        assert!(!default.coop_matrix, "the fp32 kernels are the default without cooperative matrices");
        let asked = MlpTiling { shared_tiles: true, coop_matrix: true, coop_layers: true, ..default };
        let err = Mlp::with_tiling(&g, &c, asked).err().expect("cooperative matrices refused where unavailable");
        let why = if msnerf::shaders::MLP_COOP_LAYER.is_none() { "shaderc-from-source" } else { "offers no" };
        assert!(err.to_string().contains(why), "{err}");
        let reg = MlpTiling { shared_tiles: false, coop_matrix: true, ..default };
        let err = Mlp::with_tiling(&g, &c, reg).err().expect("cooperative matrices need the shared tiles");
        assert!(err.to_string().contains("shared=1"), "{err}");
        eprintln!(
            "note: no cooperative matrices on {} in this build (coopmat: {}): checked the fallback and the refusal",
            g.caps().name,
            g.caps().cooperative_matrix
        );
        return;
    }
    assert!(default.coop_matrix, "cooperative matrices are the default where available");
    let only_wgrad = MlpTiling { coop_matrix: true, coop_layers: false, shared_tiles: true, ..default };
    check_with(&g, &cfg(63, 6, 64, 2, Activation::Sigmoid), 777, 3, only_wgrad, false);
    check_tiny_deltas(&g, only_wgrad);
    let coop = MlpTiling { coop_layers: true, ..only_wgrad };
    check_with(&g, &c, 1003, 1, coop, false);
    check_with(&g, &MlpConfig { half_activations: true, ..cfg(10, 1, 16, 1, Activation::None) }, 517, 2, coop, false);
    check_with(&g, &cfg(63, 6, 64, 2, Activation::Sigmoid), 777, 3, coop, false);
    check_with(&g, &cfg(79, 6, 128, 2, Activation::Sigmoid), 2049, 9, coop, false);
    check_with(
        &g,
        &MlpConfig { half_activations: true, ..cfg(79, 6, 128, 2, Activation::Sigmoid) },
        211,
        9,
        coop,
        false,
    );
    check_with(&g, &cfg(20, 3, 32, 3, Activation::Exponential), 301, 5, coop, false);
    check_with(&g, &cfg(32, 128, 128, 2, Activation::Sigmoid), 203, 4, coop, false);
    check_with(&g, &cfg(16, 3, 16, 1, Activation::None), 70_001, 12, coop, false);
    check_tiny_deltas(&g, coop);
}

/// Output deltas below 5e-7 (a mean loss over 32768 rays and six bands): fp16 holds them only as subnormals
/// (steps of 6e-8: about 20 % error in these sums unscaled, by an f64 check), so the kernels must scale them.
/// Gradients match to 1 %.
fn check_tiny_deltas(g: &Context, tiling: MlpTiling) {
    let c = cfg(32, 6, 64, 2, Activation::Sigmoid);
    let mlp = Mlp::with_tiling(g, &c, tiling).expect("mlp");
    let n = 4096;
    let w = weights(&c, 41);
    let params = LargeArray::<f32>::new(g, "params", w.len(), MemoryCategory::Parameters).expect("params");
    params.upload(g, 0, &w).expect("upload");
    let grads = LargeArray::<f32>::new(g, "grads", w.len(), MemoryCategory::Gradients).expect("grads");
    let mut r = rng(42);
    let x: Vec<f32> = (0..n * c.in_pad()).map(|_| r.random_range(-1.0..1.0)).collect();
    let dy_host: Vec<f32> = (0..n * c.n_output).map(|_| r.random_range(-5e-7..5e-7)).collect();
    let input = buf(g, "x", &x);
    let out = zeros(g, "y", n * c.n_output);
    let dy = buf(g, "dy", &dy_host);
    let acts = zeros(g, "acts", c.hidden_floats(n));
    let deltas = zeros(g, "deltas", c.delta_floats(n));
    let scratch = zeros(g, "scratch", mlp.wgrad_scratch_floats(n));
    let dx = zeros(g, "dx", n * c.in_pad());
    let p = ParamSlice { array: &params, offset: 0 };
    let gs = ParamSlice { array: &grads, offset: 0 };
    let xin = RowSlice { buf: &input, stride: c.in_pad(), col: 0 };
    let y = RowSlice { buf: &out, stride: c.n_output, col: 0 };
    let mut rec = g.recorder("tiny deltas").expect("recorder");
    for ch in grads.chunks() {
        ops::fill(&mut rec, ch, 0.0f32, 0, ch.len()).expect("zero grads");
    }
    mlp.forward(&mut rec, p, xin, n, y, &acts).expect("forward");
    let bufs = MlpTrainBuffers { acts: &acts, deltas: &deltas, scratch: &scratch };
    let dys = RowSlice { buf: &dy, stride: c.n_output, col: 0 };
    let dxs = RowSlice { buf: &dx, stride: c.in_pad(), col: 0 };
    mlp.backward(&mut rec, p, gs, (xin, y, dys), n, &bufs, Some(dxs)).expect("backward");
    rec.submit_and_wait().expect("submit");
    let got_g = grads.download(g).expect("grads");
    let got_dx = g.download(&dx).expect("dx");
    let got_acts = stored_activations(&c, &g.download(&acts).expect("acts"));
    let got_y = g.download(&out).expect("y");
    let w64: Vec<f64> = w.iter().map(|&v| v as f64).collect();
    let mut want_g = vec![0.0f64; w.len()];
    let mut worst_dx = 0.0f64;
    for i in 0..n {
        let row: Vec<f64> = x[i * c.in_pad()..(i + 1) * c.in_pad()].iter().map(|&v| v as f64).collect();
        let d: Vec<f64> = dy_host[i * c.n_output..(i + 1) * c.n_output].iter().map(|&v| v as f64).collect();
        // From the kernels' stored forward pass (its ReLU masks), as check_with does for cooperative matrices.
        let (stored, ys) = stored_forward(&c, (&got_acts, n), (&got_y, c.n_output, 0), i);
        let dxv = twin::backward_from(&c, &w64, &row, (&stored, &ys), &d, &mut want_g);
        let scale = dxv.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-30);
        for (k, want) in dxv.iter().enumerate() {
            worst_dx = worst_dx.max((got_dx[i * c.in_pad() + k] as f64 - want).abs() / scale);
        }
    }
    assert!(worst_dx < 1e-2, "{tiling:?}: input gradient off by {worst_dx} of its row's largest value");
    let mean = want_g.iter().map(|v| v.abs()).sum::<f64>() / want_g.len() as f64;
    let worst = got_g.iter().zip(&want_g).map(|(&a, b)| (a as f64 - b).abs() / (b.abs() + mean)).fold(0.0, f64::max);
    assert!(worst < 1e-2, "{tiling:?}: weight gradients off by {worst} (relative to |g| + mean |g| = {mean})");
}

#[test]
fn twin_stores_fp16_activations_exactly_representable() {
    let c = MlpConfig { half_activations: true, ..cfg(20, 3, 32, 3, Activation::Exponential) };
    let w: Vec<f64> = weights(&c, 21).iter().map(|&v| v as f64).collect();
    let mut r = rng(22);
    let x: Vec<f64> = (0..c.in_pad()).map(|_| r.random_range(-1.0..1.0)).collect();
    let (hidden, _) = twin::forward(&c, &w, &x);
    let (full, _) = twin::forward(&MlpConfig { half_activations: false, ..c.clone() }, &w, &x);
    for (h, f) in hidden[0].iter().zip(&full[0]) {
        assert_eq!(half::f16::from_f64(*h).to_f64(), *h, "{h} is an fp16 value");
        assert_eq!(*h, half::f16::from_f64(*f).to_f64(), "the first layer is the fp32 twin's, rounded");
    }
    assert!(hidden.iter().flatten().all(|v| half::f16::from_f64(*v).to_f64() == *v), "every layer stored as fp16");
}

#[test]
fn twin_backward_matches_finite_differences() {
    for (c, seed) in [(cfg(20, 5, 16, 2, Activation::Sigmoid), 7u64), (cfg(9, 2, 32, 1, Activation::Exponential), 8)] {
        let w: Vec<f64> = weights(&c, seed).iter().map(|&v| v as f64).collect();
        let mut r = rng(seed + 10);
        let x: Vec<f64> = (0..c.in_pad()).map(|_| r.random_range(-1.0..1.0)).collect();
        let dy: Vec<f64> = (0..c.n_output).map(|_| r.random_range(-1.0..1.0)).collect();
        let loss = |w: &[f64], x: &[f64]| twin::forward(&c, w, x).1.iter().zip(&dy).map(|(a, b)| a * b).sum::<f64>();
        let mut gw = vec![0.0; w.len()];
        let gx = twin::backward(&c, &w, &x, &dy, &mut gw);
        let h = 1e-6;
        for j in (0..w.len()).step_by(7) {
            let (mut wp, mut wm) = (w.clone(), w.clone());
            wp[j] += h;
            wm[j] -= h;
            let fd = (loss(&wp, &x) - loss(&wm, &x)) / (2.0 * h);
            assert!(common::close(gw[j], fd, 1e-7, 1e-5), "{c:?} dW[{j}]: {} vs {fd}", gw[j]);
        }
        for k in 0..x.len() {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[k] += h;
            xm[k] -= h;
            let fd = (loss(&w, &xp) - loss(&w, &xm)) / (2.0 * h);
            assert!(common::close(gx[k], fd, 1e-7, 1e-5), "{c:?} dx[{k}]: {} vs {fd}", gx[k]);
        }
    }
}

#[test]
fn weights_across_a_chunk_boundary_are_refused() {
    let g = gpu();
    let c = cfg(16, 16, 16, 1, Activation::None);
    let mlp = Mlp::new(&g, &c).expect("mlp");
    let params =
        LargeArray::<f32>::with_chunk_shift(&g, "small chunks", 4096, MemoryCategory::Parameters, 9).expect("params");
    let x = zeros(&g, "x", 16 * 4);
    let y = zeros(&g, "y", 16 * 4);
    let mut rec = g.recorder("refuse").expect("recorder");
    let err = mlp
        .infer(
            &mut rec,
            ParamSlice { array: &params, offset: 400 },
            RowSlice { buf: &x, stride: 16, col: 0 },
            4,
            RowSlice { buf: &y, stride: 16, col: 0 },
            &zeros(&g, "scratch", 16 * 4),
        )
        .expect_err("512 floats at 400 cross the 512-float chunk boundary");
    assert!(err.to_string().contains("chunk boundary"), "{err}");
    let _ = BufferDesc { name: "unused", len: 0, category: MemoryCategory::Other };
}

#[test]
fn inference_in_one_block_or_many_gives_the_forward_pass() {
    // More rows than one inference block: with the minimal scratch `infer` runs blocks of INFER_BLOCK_ROWS rows,
    // with a scratch that holds every row's hidden layers (the trainer passes the activations buffer) one block.
    // Both must equal the training forward pass bit for bit: the same kernels on the same rows.
    use msnerf::nn::mlp::INFER_BLOCK_ROWS;
    let g = gpu();
    let c = cfg(10, 1, 16, 1, Activation::None);
    let mlp = Mlp::new(&g, &c).expect("mlp");
    let n = INFER_BLOCK_ROWS + 777;
    let mut r = rng(12);
    let w = weights(&c, 3);
    let params = LargeArray::<f32>::new(&g, "params", w.len(), MemoryCategory::Parameters).expect("params");
    params.upload(&g, 0, &w).expect("upload");
    let x: Vec<f32> = (0..n * c.in_pad()).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let input = buf(&g, "x", &x);
    let xin = RowSlice { buf: &input, stride: c.in_pad(), col: 0 };
    let p = ParamSlice { array: &params, offset: 0 };
    let outs: Vec<GpuBuffer<f32>> = (0..3).map(|i| zeros(&g, &format!("y{i}"), n)).collect();
    let y = |i: usize| RowSlice { buf: &outs[i], stride: 1, col: 0 };
    let acts = zeros(&g, "acts", c.hidden_floats(n));
    let small = zeros(&g, "small scratch", c.infer_scratch_floats(n));
    assert!(small.len() < acts.len(), "the minimal scratch holds one block only");
    let mut rec = g.recorder("infer blocks").expect("recorder");
    mlp.forward(&mut rec, p, xin, n, y(0), &acts).expect("forward");
    let blocks_before = rec.barrier_count();
    mlp.infer(&mut rec, p, xin, n, y(1), &small).expect("infer in blocks");
    let blocks = rec.barrier_count() - blocks_before;
    let one_before = rec.barrier_count();
    mlp.infer(&mut rec, p, xin, n, y(2), &acts).expect("infer in one block");
    let one = rec.barrier_count() - one_before;
    rec.submit_and_wait().expect("submit");
    let want = g.download(&outs[0]).expect("forward");
    assert_eq!(g.download(&outs[1]).expect("blocks"), want, "blocks of INFER_BLOCK_ROWS rows");
    assert_eq!(g.download(&outs[2]).expect("one block"), want, "one block");
    assert!(one < blocks, "one block waits less: {one} barriers against {blocks}");
}
