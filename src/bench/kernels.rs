//! `msnerf bench kernels`: hash grid forward/backward in points/s and MLP forward+backward in GFLOP/s, at
//! nerfacto's and Multispectral-NeRF Table 1's sizes, on the selected device. On a CPU device (lavapipe) the same
//! MLP layer shapes also run through `matrixmultiply`'s threaded sgemm on the same cores, so the table shows how
//! close the Vulkan kernels get to what the CPU can do.
//!
//! Timing: wall clock of whole submissions (one warm-up, then the median of `repeats`), since lavapipe's
//! timestamps measure CPU time anyway; the per-kernel GPU timestamps are reported alongside.

use crate::gpu::{Context, GpuBuffer, GpuResult, KernelTime, LargeArray, MemoryCategory, Recorder};
use crate::nn::hashgrid::{HashGrid, HashGridConfig, OutputSlot};
use crate::nn::mlp::{Activation, Mlp, MlpConfig, MlpTiling, MlpTrainBuffers};
use crate::nn::{ParamSlice, RowSlice};
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::time::Instant;

/// Points per invocation of the run-combining backward that the "rays run8" column times (the JSON's
/// `backward_rays_run8_mpts_per_s`; the default run length on GPUs).
const BENCH_RUN: u32 = 8;

#[derive(Clone, Debug, Serialize)]
pub struct HashResult {
    pub name: String,
    pub points: usize,
    pub params: usize,
    pub forward_mpts_per_s: f64,
    pub backward_mpts_per_s: f64,
    /// Hash-gradient atomic updates per second (8 corners x F features per point and level).
    pub backward_matomics_per_s: f64,
    /// The parameter backward on ray-ordered points (48 consecutive samples along each ray, as training produces
    /// them): one point per invocation, and with run combining over 8 consecutive points (hashgrid_bwd.comp).
    pub backward_rays_mpts_per_s: f64,
    pub backward_rays_run8_mpts_per_s: f64,
    /// Speed-up of reading the tables as texel buffers against reading them through device addresses, on
    /// ray-ordered points: the median of per-repeat ratios of the two timed back to back (this machine's speed
    /// drifts), for the forward and for the input gradient. `None` where no level can be bound as texels.
    pub forward_texel_speedup: Option<f64>,
    pub input_grad_texel_speedup: Option<f64>,
    /// The same for the parameter gradient: its texel gather of the corners' gradient entries before the atomics
    /// (`hashgrid_bwd_prefetch`) against the atomics alone.
    pub param_grad_prefetch_speedup: Option<f64>,
    /// Levels read as texels in those (the others straddle chunks and keep the device-address read).
    pub texel_levels: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct MlpResult {
    pub name: String,
    pub shape: String,
    pub rows: usize,
    /// Kernels used (`MlpTiling`): shared-memory tiles (GPUs) or register tiles (CPU devices), and the register
    /// tiles' block sizes: unrolled multiply-adds per layer kernel and the weight-gradient tile.
    pub shared_tiles: bool,
    /// The cooperative-matrix (tensor-core) kernels on those tiles: weight gradients, and layers.
    pub coop_matrix: bool,
    pub coop_layers: bool,
    pub mac_budget: usize,
    pub wgrad_tile_j: usize,
    pub wgrad_tile_k: usize,
    /// From host wall-clock time per pass, the submission and the wait included (on a GPU a 65k-row pass takes
    /// well under a millisecond, so this is mostly the round trip).
    pub forward_gflops: f64,
    pub train_gflops: f64,
    /// Forward+backward from the summed per-kernel timestamps of one pass: the kernels' own speed. `None` when the
    /// device has no timestamps.
    pub train_kernel_gflops: Option<f64>,
    /// Per kernel of one training pass (forward + backward): calls and ms (device timestamps; CPU time on lavapipe).
    pub train_kernels: Vec<KernelTime>,
    /// The same layers through the CPU sgemm (forward + both backward products), when the device is a CPU.
    pub cpu_sgemm_gflops: Option<f64>,
    /// On a CPU device: our forward+backward pass and the sgemm are timed back to back in every repeat, and this
    /// is the median over repeats of sgemm time / our time (our GFLOP/s as a fraction of the sgemm's, measured
    /// under the same load: this virtual machine's speed drifts between minutes, not within one pair).
    pub sgemm_ratio: Option<f64>,
    /// Register tiles (`shared_tiles` off): a training pass with the layers' rows read through texel views against
    /// the same pass with storage-buffer reads (`MlpTiling::texel_rows` on and off), timed back to back in every
    /// repeat, median of the per-repeat ratios (storage time / texel time). `None` on shared tiles.
    pub texel_rows_speedup: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct KernelBench {
    pub device: String,
    pub driver: String,
    pub host_threads: usize,
    pub hash: Vec<HashResult>,
    pub mlp: Vec<MlpResult>,
}

fn time_ms(repeats: usize, mut f: impl FnMut() -> GpuResult<()>) -> GpuResult<f64> {
    f()?; // warm-up: pipeline compilation, staging growth
    let mut t: Vec<f64> = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    Ok(median(t))
}

/// The middle value (the upper one of an even count); `v` is not empty.
/// `run(false)` then `run(true)`, timed back to back in every repeat after one untimed pair (pipeline compilation):
/// the median of the per-repeat ratios time(false) / time(true), the speed-up of `true`. Paired so that this
/// machine's drift between minutes cancels.
fn paired_speedup(repeats: usize, mut run: impl FnMut(bool) -> GpuResult<()>) -> GpuResult<f64> {
    let mut r = Vec::with_capacity(repeats);
    for k in 0..=repeats.max(1) {
        let mut t = [0.0; 2];
        for (on, t) in [false, true].into_iter().zip(&mut t) {
            let s = Instant::now();
            run(on)?;
            *t = s.elapsed().as_secs_f64();
        }
        if k > 0 {
            r.push(t[0] / t[1]);
        }
    }
    Ok(median(r))
}

fn median(v: Vec<f64>) -> f64 {
    crate::util::stats::upper_median(&v)
}

fn random(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| r.random_range(lo..hi)).collect()
}

fn zeros(ctx: &Context, name: &str, len: usize) -> GpuResult<GpuBuffer<f32>> {
    GpuBuffer::from_slice(ctx, name, MemoryCategory::Activations, &vec![0.0f32; len])
}

fn run_recorded(ctx: &Context, f: &dyn Fn(&mut Recorder) -> GpuResult<()>) -> GpuResult<()> {
    let mut rec = ctx.recorder("bench")?;
    f(&mut rec)?;
    rec.submit_and_wait().map(|_| ())
}

pub fn bench_hash(
    ctx: &Context,
    name: &str,
    cfg: &HashGridConfig,
    points: usize,
    repeats: usize,
) -> GpuResult<HashResult> {
    // One point per backward invocation, whatever the device's default; run combining is timed on its own below.
    let grid = HashGrid::with_backward_run(ctx, cfg, 1)?;
    let n_params = cfg.n_params();
    let params = LargeArray::<f32>::new(ctx, "bench grid", n_params, MemoryCategory::Parameters)?;
    params.upload(ctx, 0, &random(n_params, -1e-4, 1e-4, 1))?;
    let grads = LargeArray::<f32>::new(ctx, "bench grads", n_params, MemoryCategory::Gradients)?;
    let pos = GpuBuffer::from_slice(ctx, "bench pos", MemoryCategory::Activations, &random(points * 3, 0.0, 1.0, 2))?;
    let w = cfg.n_output();
    let out = zeros(ctx, "bench enc", points * w)?;
    let dy = GpuBuffer::from_slice(ctx, "bench dy", MemoryCategory::Activations, &random(points * w, -1.0, 1.0, 3))?;
    let p = ParamSlice { array: &params, offset: 0 };
    let slot = OutputSlot { stride: w, col: 0, pad_to: w, pad_value: 0.0 };
    let fwd = time_ms(repeats, || run_recorded(ctx, &|rec| grid.forward(rec, p, &pos, points, &out, slot)))?;
    let g = ParamSlice { array: &grads, offset: 0 };
    let dys = RowSlice { buf: &dy, stride: w, col: 0 };
    let bwd = time_ms(repeats, || run_recorded(ctx, &|rec| grid.backward_params(rec, g, &pos, points, dys)))?;
    let rays = GpuBuffer::from_slice(ctx, "bench ray points", MemoryCategory::Activations, &ray_points(points, 48))?;
    let bwd_rays = time_ms(repeats, || run_recorded(ctx, &|rec| grid.backward_params(rec, g, &rays, points, dys)))?;
    let mut paired = HashGrid::with_backward_run(ctx, cfg, 1)?;
    paired.set_texel_reads(true);
    paired.set_one_dispatch(false); // texels are read by the per-level kernels (GPUs: one dispatch up to 2^20 points)
    let texel_levels = paired.texel_levels(p)?;
    let dp = zeros(ctx, "bench dp", points * 3)?;
    let mut ratio = |which: usize| -> GpuResult<Option<f64>> {
        let speedup = paired_speedup(repeats, |texel| {
            paired.set_texel_reads(texel);
            let grid = &paired;
            run_recorded(ctx, &|rec| match which {
                0 => grid.forward(rec, p, &rays, points, &out, slot),
                1 => grid.backward_input(rec, p, &rays, points, dys, &dp),
                _ => grid.backward_params(rec, g, &rays, points, dys),
            })
        })?;
        Ok(Some(speedup))
    };
    let (fwd_texel, input_texel, prefetch) =
        if texel_levels > 0 { (ratio(0)?, ratio(1)?, ratio(2)?) } else { (None, None, None) };
    let grid8 = HashGrid::with_backward_run(ctx, cfg, BENCH_RUN)?;
    let bwd_run8 = time_ms(repeats, || run_recorded(ctx, &|rec| grid8.backward_params(rec, g, &rays, points, dys)))?;
    let atomics = (points * cfg.n_levels as usize * 8 * cfg.features_per_level as usize) as f64;
    Ok(HashResult {
        name: name.into(),
        points,
        params: n_params,
        forward_mpts_per_s: points as f64 / fwd / 1e3,
        backward_mpts_per_s: points as f64 / bwd / 1e3,
        backward_matomics_per_s: atomics / bwd / 1e3,
        backward_rays_mpts_per_s: points as f64 / bwd_rays / 1e3,
        backward_rays_run8_mpts_per_s: points as f64 / bwd_run8 / 1e3,
        forward_texel_speedup: fwd_texel,
        input_grad_texel_speedup: input_texel,
        param_grad_prefetch_speedup: prefetch,
        texel_levels,
    })
}

/// `points` hash-grid inputs in [0,1]^3 ordered as training produces them: `per_ray` consecutive samples, evenly
/// spaced over half the cube's width along a random ray.
fn ray_points(points: usize, per_ray: usize) -> Vec<f32> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut out = Vec::with_capacity(points * 3);
    while out.len() < points * 3 {
        let o: [f32; 3] = std::array::from_fn(|_| r.random_range(0.25..0.75));
        let d: [f32; 3] = std::array::from_fn(|_| r.random_range(-1.0f32..1.0));
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
        for i in 0..per_ray {
            let t = 0.5 * i as f32 / per_ray as f32 - 0.25;
            out.extend((0..3).map(|k| (o[k] + t * d[k] / n).clamp(0.0, 1.0)));
        }
    }
    out.truncate(points * 3);
    out
}

pub fn bench_mlp(ctx: &Context, name: &str, cfg: &MlpConfig, rows: usize, repeats: usize) -> GpuResult<MlpResult> {
    let mlp = Mlp::new(ctx, cfg)?;
    let n_params = cfg.n_params();
    let params = LargeArray::<f32>::new(ctx, "bench mlp", n_params, MemoryCategory::Parameters)?;
    params.upload(ctx, 0, &random(n_params, -0.1, 0.1, 4))?;
    let grads = LargeArray::<f32>::new(ctx, "bench mlp grads", n_params, MemoryCategory::Gradients)?;
    let x =
        GpuBuffer::from_slice(ctx, "bench x", MemoryCategory::Activations, &random(rows * cfg.in_pad(), -1.0, 1.0, 5))?;
    let y = zeros(ctx, "bench y", rows * cfg.n_output)?;
    let dy = GpuBuffer::from_slice(
        ctx,
        "bench dy",
        MemoryCategory::Activations,
        &random(rows * cfg.n_output, -1.0, 1.0, 6),
    )?;
    let acts = zeros(ctx, "bench acts", cfg.hidden_floats(rows))?;
    let deltas = zeros(ctx, "bench deltas", cfg.delta_floats(rows))?;
    let scratch = zeros(ctx, "bench scratch", mlp.wgrad_scratch_floats(rows))?;
    let dx = zeros(ctx, "bench dx", rows * cfg.in_pad())?;
    let p = ParamSlice { array: &params, offset: 0 };
    let g = ParamSlice { array: &grads, offset: 0 };
    let xs = RowSlice { buf: &x, stride: cfg.in_pad(), col: 0 };
    let ys = RowSlice { buf: &y, stride: cfg.n_output, col: 0 };
    let dys = RowSlice { buf: &dy, stride: cfg.n_output, col: 0 };
    let dxs = RowSlice { buf: &dx, stride: cfg.in_pad(), col: 0 };
    let bufs = MlpTrainBuffers { acts: &acts, deltas: &deltas, scratch: &scratch };
    let infer_scratch = zeros(ctx, "bench infer scratch", cfg.infer_scratch_floats(rows))?;
    let fwd = time_ms(repeats, || run_recorded(ctx, &|rec| mlp.infer(rec, p, xs, rows, ys, &infer_scratch)))?;
    let train_pass = |rec: &mut Recorder| {
        mlp.forward(rec, p, xs, rows, ys, &acts)?;
        mlp.backward(rec, p, g, (xs, ys, dys), rows, &bufs, Some(dxs))
    };
    let (train, cpu_sgemm_gflops, sgemm_ratio) = if ctx.caps().is_cpu {
        let (ours, sgemm, ratio) = paired_with_sgemm(cfg, rows, repeats, || run_recorded(ctx, &train_pass))?;
        (ours, Some(3.0 * 2.0 * rows as f64 * cfg.macs_per_row() as f64 / sgemm / 1e6), Some(ratio))
    } else {
        (time_ms(repeats, || run_recorded(ctx, &train_pass))?, None, None)
    };
    let texel_rows_speedup = if mlp.tiling.shared_tiles {
        None
    } else {
        let with = |texel_rows| Mlp::with_tiling(ctx, cfg, MlpTiling { texel_rows, ..mlp.tiling });
        let (storage, texel) = (with(false)?, with(true)?);
        Some(paired_speedup(repeats, |texel_rows| {
            let m = if texel_rows { &texel } else { &storage };
            run_recorded(ctx, &|rec: &mut Recorder| {
                m.forward(rec, p, xs, rows, ys, &acts)?;
                m.backward(rec, p, g, (xs, ys, dys), rows, &bufs, Some(dxs))
            })
        })?)
    };
    let mut rec = ctx.recorder("bench")?;
    train_pass(&mut rec)?;
    let train_kernels = rec.submit_and_wait()?.by_kernel();
    let flop = 2.0 * rows as f64 * cfg.macs_per_row() as f64;
    let kernel_ms: f64 = train_kernels.iter().map(|k| k.total_ms).sum();
    let train_kernel_gflops = (kernel_ms > 0.0).then(|| 3.0 * flop / kernel_ms / 1e6);
    Ok(MlpResult {
        name: name.into(),
        shape: shape(cfg),
        rows,
        shared_tiles: mlp.tiling.shared_tiles,
        coop_matrix: mlp.tiling.coop_matrix,
        coop_layers: mlp.tiling.coop_layers,
        mac_budget: mlp.tiling.mac_budget,
        wgrad_tile_j: mlp.tiling.wgrad_tile_j,
        wgrad_tile_k: mlp.tiling.wgrad_tile_k,
        train_kernels,
        forward_gflops: flop / fwd / 1e6,
        train_gflops: 3.0 * flop / train / 1e6,
        train_kernel_gflops,
        cpu_sgemm_gflops,
        sgemm_ratio,
        texel_rows_speedup,
    })
}

/// `ours` (one forward+backward pass) and the same shapes through the CPU sgemm, each timed once per repeat, back
/// to back, after one warm-up of each: (median ms of ours, median ms of the sgemm, median of sgemm / ours).
fn paired_with_sgemm(
    cfg: &MlpConfig,
    rows: usize,
    repeats: usize,
    mut ours: impl FnMut() -> GpuResult<()>,
) -> GpuResult<(f64, f64, f64)> {
    let mut sgemm = cpu_sgemm_pass(cfg, rows);
    ours()?;
    sgemm();
    let (mut a, mut b, mut r) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats.max(1) {
        let s = Instant::now();
        ours()?;
        let t_ours = s.elapsed().as_secs_f64() * 1e3;
        let s = Instant::now();
        sgemm();
        let t_sgemm = s.elapsed().as_secs_f64() * 1e3;
        a.push(t_ours);
        b.push(t_sgemm);
        r.push(t_sgemm / t_ours);
    }
    Ok((median(a), median(b), median(r)))
}

fn shape(c: &MlpConfig) -> String {
    let mut s = format!("{}", c.in_pad());
    for (r, _) in c.layer_shapes() {
        s += &format!("-{r}");
    }
    s
}

/// Forward (Y = X W^T per layer) plus the two backward products (dX = dY W, dW = dY^T X) through
/// `matrixmultiply::sgemm`, on the same shapes: one call runs one pass.
fn cpu_sgemm_pass(cfg: &MlpConfig, rows: usize) -> impl FnMut() {
    let mats = cfg.layer_shapes();
    let widest = mats.iter().map(|(r, c)| (*r).max(*c)).max().unwrap_or(16);
    let w: Vec<Vec<f32>> = mats.iter().enumerate().map(|(i, (r, c))| random(r * c, -0.1, 0.1, 10 + i as u64)).collect();
    let mut acts: Vec<Vec<f32>> = vec![random(rows * cfg.in_pad(), -1.0, 1.0, 7)];
    acts.extend(mats.iter().map(|(r, _)| vec![0.0f32; rows * r]));
    let mut d_a = vec![0.0f32; rows * widest];
    let mut d_b = vec![0.0f32; rows * widest];
    let mut dw = vec![0.0f32; widest * widest];
    move || {
        for (m, &(r, c)) in mats.iter().enumerate() {
            let (head, tail) = acts.split_at_mut(m + 1);
            // Y (rows x r) = X (rows x c) * W^T (c x r): W is r x c row-major, so W^T has strides (1, c).
            unsafe {
                matrixmultiply::sgemm(
                    rows,
                    c,
                    r,
                    1.0,
                    head[m].as_ptr(),
                    c as isize,
                    1,
                    w[m].as_ptr(),
                    1,
                    c as isize,
                    0.0,
                    tail[0].as_mut_ptr(),
                    r as isize,
                    1,
                );
            }
        }
        for (m, &(r, c)) in mats.iter().enumerate().rev() {
            unsafe {
                // dX (rows x c) = dY (rows x r) * W (r x c)
                matrixmultiply::sgemm(
                    rows,
                    r,
                    c,
                    1.0,
                    d_a.as_ptr(),
                    r as isize,
                    1,
                    w[m].as_ptr(),
                    c as isize,
                    1,
                    0.0,
                    d_b.as_mut_ptr(),
                    c as isize,
                    1,
                );
                // dW (r x c) = dY^T (r x rows) * X (rows x c)
                matrixmultiply::sgemm(
                    r,
                    rows,
                    c,
                    1.0,
                    d_a.as_ptr(),
                    1,
                    r as isize,
                    acts[m].as_ptr(),
                    c as isize,
                    1,
                    0.0,
                    dw.as_mut_ptr(),
                    c as isize,
                    1,
                );
            }
            std::mem::swap(&mut d_a, &mut d_b);
        }
    }
}

/// Hash grids of both model profiles (nerfacto defaults; Multispectral-NeRF Table 1).
pub fn grid_profiles() -> Vec<(&'static str, HashGridConfig)> {
    let grid = |levels, log2, max| HashGridConfig {
        n_levels: levels,
        features_per_level: 2,
        log2_hashmap_size: log2,
        base_resolution: 16,
        max_resolution: max,
    };
    vec![
        ("nerfacto field grid", grid(16, 19, 2048)),
        ("nerfacto proposal grid", grid(5, 17, 128)),
        ("table1 field grid", grid(16, 21, 4096)),
    ]
}

/// MLPs of both model profiles, with 6 bands.
pub fn mlp_profiles() -> Vec<(&'static str, MlpConfig)> {
    let mlp = |n_input, n_output, width, n_hidden_layers, act| MlpConfig {
        n_input,
        n_output,
        width,
        n_hidden_layers,
        output_activation: act,
        half_activations: false,
    };
    vec![
        ("nerfacto density", mlp(32, 16, 64, 1, Activation::None)),
        ("nerfacto colour (6 bands)", mlp(63, 6, 64, 2, Activation::Sigmoid)),
        ("nerfacto proposal", mlp(10, 1, 16, 1, Activation::None)),
        ("table1 density", mlp(32, 32, 128, 1, Activation::None)),
        ("table1 colour (6 bands)", mlp(79, 6, 128, 2, Activation::Sigmoid)),
        ("table1 density, fp16 activations", half(mlp(32, 32, 128, 1, Activation::None))),
        ("table1 colour (6 bands), fp16 activations", half(mlp(79, 6, 128, 2, Activation::Sigmoid))),
    ]
}

fn half(c: MlpConfig) -> MlpConfig {
    MlpConfig { half_activations: true, ..c }
}

pub fn run(ctx: &Context, points: usize, rows: usize, repeats: usize, filter: Option<&str>) -> GpuResult<KernelBench> {
    let keep = |name: &str| filter.is_none_or(|f| name.contains(f));
    let mut hash = Vec::new();
    for (name, cfg) in grid_profiles().iter().filter(|(n, _)| keep(n)) {
        hash.push(bench_hash(ctx, name, cfg, points, repeats)?);
    }
    let mut mlp = Vec::new();
    for (name, cfg) in mlp_profiles().iter().filter(|(n, _)| keep(n)) {
        mlp.push(bench_mlp(ctx, name, cfg, rows, repeats)?);
    }
    Ok(KernelBench {
        device: ctx.caps().name.clone(),
        driver: format!("{} {}", ctx.caps().driver_name, ctx.caps().driver_info),
        host_threads: std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        hash,
        mlp,
    })
}

impl KernelBench {
    pub fn table(&self) -> String {
        let mut s = format!("device: {} ({}), host threads: {}\n\n", self.device, self.driver, self.host_threads);
        s += &format!(
            "{:<26} {:>9} {:>11} {:>12} {:>13} {:>14} {:>14} {:>14} {:>10} {:>10} {:>12}\n",
            "hash grid",
            "points",
            "params",
            "fwd Mpt/s",
            "bwd Mpt/s",
            "bwd Matomic/s",
            "rays bwd Mpt/s",
            "rays run8 Mpt/s",
            "texel fwd",
            "texel dp",
            "prefetch bwd"
        );
        for h in &self.hash {
            s += &format!(
                "{:<26} {:>9} {:>11} {:>12.2} {:>13.2} {:>14.1} {:>14.2} {:>14.2} {:>10} {:>10} {:>12}\n",
                h.name,
                h.points,
                h.params,
                h.forward_mpts_per_s,
                h.backward_mpts_per_s,
                h.backward_matomics_per_s,
                h.backward_rays_mpts_per_s,
                h.backward_rays_run8_mpts_per_s,
                h.forward_texel_speedup.map_or("-".into(), |r| format!("{r:.2}x")),
                h.input_grad_texel_speedup.map_or("-".into(), |r| format!("{r:.2}x")),
                h.param_grad_prefetch_speedup.map_or("-".into(), |r| format!("{r:.2}x"))
            );
        }
        s += &format!(
            "\n{:<26} {:<18} {:>8} {:>11} {:>13} {:>14} {:>12} {:>7} {:>11}\n",
            "MLP",
            "shape",
            "rows",
            "fwd GFLOP/s",
            "train GFLOP/s",
            "train, kernels",
            "CPU sgemm",
            "ratio",
            "texel rows"
        );
        for m in &self.mlp {
            let cpu = m.cpu_sgemm_gflops.map_or("-".into(), |c| format!("{c:.1}"));
            let ratio = m.sgemm_ratio.map_or("-".into(), |r| format!("{:.0}%", 100.0 * r));
            let kernels = m.train_kernel_gflops.map_or("-".into(), |g| format!("{g:.2}"));
            let texel = m.texel_rows_speedup.map_or("-".into(), |r| format!("{r:.2}x"));
            s += &format!(
                "{:<26} {:<18} {:>8} {:>11.2} {:>13.2} {:>14} {:>12} {:>7} {:>11}\n",
                m.name, m.shape, m.rows, m.forward_gflops, m.train_gflops, kernels, cpu, ratio, texel
            );
        }
        s
    }
}
