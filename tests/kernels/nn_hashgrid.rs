//! Hash grid kernels against the CPU twin (`msnerf::reference::hashgrid`) and finite differences.
//! Tolerances: forward and input gradient fp32 |a-b| <= 1e-5 + 1e-4|b|; parameter gradients (fp32 atomics in
//! any order) judged on the 99th percentile of relative error, as tiny-cuda-nn's tests do.

use crate::common;
use common::{assert_all_close_f32, gpu, rng};
use msnerf::gpu::{BufferDesc, Context, GpuBuffer, LargeArray, MemoryCategory};
use msnerf::nn::hashgrid::{self, HashGrid, HashGridConfig, OutputSlot};
use msnerf::nn::{ParamSlice, RowSlice};
use msnerf::ops;
use msnerf::reference::hashgrid as twin;
use rand::Rng;

fn nerfacto_field() -> HashGridConfig {
    HashGridConfig {
        n_levels: 16,
        features_per_level: 2,
        log2_hashmap_size: 19,
        base_resolution: 16,
        max_resolution: 2048,
    }
}

/// Small grid with dense and hashed levels.
fn small() -> HashGridConfig {
    HashGridConfig { n_levels: 6, features_per_level: 2, log2_hashmap_size: 12, base_resolution: 4, max_resolution: 96 }
}

#[test]
fn level_tables_match_tiny_cuda_nn() {
    // spec/nerfacto.md §3.2, computed level tables.
    let field = nerfacto_field();
    let lv = field.levels();
    let res: Vec<u32> = lv.iter().map(|l| l.res).collect();
    assert_eq!(&res[..15], &[16, 23, 31, 43, 59, 81, 112, 154, 213, 295, 407, 562, 777, 1073, 1483]);
    assert!((2047..=2049).contains(&res[15]), "finest level ~2048, got {}", res[15]);
    let entries: Vec<u32> = lv.iter().map(|l| l.entries).collect();
    assert_eq!(&entries[..5], &[4096, 12168, 29792, 79512, 205384]);
    assert!(lv[..5].iter().all(|l| l.hashed == 0) && lv[5..].iter().all(|l| l.hashed == 1 && l.entries == 1 << 19));
    assert_eq!(field.n_entries(), 6_098_120);
    assert!((field.per_level_scale() - 1.381913).abs() < 1e-6);
    let prop0 = HashGridConfig {
        n_levels: 5,
        features_per_level: 2,
        log2_hashmap_size: 17,
        base_resolution: 16,
        max_resolution: 128,
    };
    let prop1 = HashGridConfig { max_resolution: 256, ..prop0.clone() };
    assert_eq!(prop0.levels().iter().map(|l| l.res).collect::<Vec<_>>(), [16, 27, 46, 77, 128]);
    assert_eq!(prop0.n_entries(), 383_264);
    assert_eq!(prop1.levels().iter().map(|l| l.res).collect::<Vec<_>>(), [16, 32, 64, 128, 256]);
    assert_eq!(prop1.n_entries(), 430_080);
    assert!(HashGridConfig { features_per_level: 3, ..small() }.validate().is_err());
}

/// Random points in [0,1]^3, kept `margin` (in cells of the finest level) away from every level's cell faces, so
/// finite differences do not cross the piecewise-linear kinks.
fn points(cfg: &HashGridConfig, n: usize, seed: u64, margin: f64) -> Vec<[f32; 3]> {
    let mut r = rng(seed);
    let levels = cfg.levels();
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let p: [f32; 3] = [r.random_range(0.0..1.0), r.random_range(0.0..1.0), r.random_range(0.0..1.0)];
        let ok = levels.iter().all(|l| {
            p.iter().all(|&x| {
                let q = x as f64 * l.scale as f64 + 0.5;
                let fr = q - q.floor();
                fr > margin && fr < 1.0 - margin
            })
        });
        if ok || margin == 0.0 {
            out.push(p);
        }
    }
    out
}

fn random_params(len: usize, seed: u64, scale: f32) -> Vec<f32> {
    let mut r = rng(seed);
    (0..len).map(|_| r.random_range(-scale..scale)).collect()
}

fn flat(p: &[[f32; 3]]) -> Vec<f32> {
    p.iter().flatten().copied().collect()
}

struct Setup {
    grid: HashGrid,
    params: LargeArray<f32>,
    host: Vec<f32>,
    offset: usize,
}

fn setup(g: &Context, cfg: &HashGridConfig, offset: usize, seed: u64) -> Setup {
    let grid = HashGrid::new(g, cfg).expect("hash grid");
    let host = random_params(cfg.n_params(), seed, 1.0);
    let params =
        LargeArray::<f32>::new(g, "grid params", offset + cfg.n_params(), MemoryCategory::Parameters).expect("params");
    params.upload(g, offset, &host).expect("upload");
    Setup { grid, params, host, offset }
}

/// How the forward and the input gradient read the tables: one dispatch per level through device addresses or as
/// texel buffers, or one dispatch for all levels (the `_levels` kernels).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reads {
    Buffer,
    Texel,
    OneDispatch,
}

const ALL_READS: [Reads; 3] = [Reads::Buffer, Reads::Texel, Reads::OneDispatch];

impl Reads {
    fn apply(self, grid: &mut HashGrid) {
        grid.set_texel_reads(self == Reads::Texel);
        grid.set_one_dispatch(self == Reads::OneDispatch);
    }

    /// The levels read as texels when the grid lies in one chunk.
    fn texel_levels(self, cfg: &HashGridConfig) -> usize {
        if self == Reads::Texel {
            cfg.n_levels as usize
        } else {
            0
        }
    }

    /// Dispatches a forward or an input gradient records: one per level, or one.
    fn dispatches(self, cfg: &HashGridConfig) -> usize {
        if self == Reads::OneDispatch {
            1
        } else {
            cfg.n_levels as usize
        }
    }
}

/// Submits `rec` with timestamps and checks that it ran `want` dispatches of `kernel` (where the queue has
/// timestamps; lavapipe's has).
fn submit_counting(rec: msnerf::gpu::Recorder, kernel: &str, want: usize, what: &str) {
    if let Some(n) = submit_and_count(rec, kernel) {
        assert_eq!(n, want, "{what}: {kernel} dispatches");
    }
}

/// Submits `rec` with timestamps and returns how many dispatches of `kernel` it ran (None without timestamps).
fn submit_and_count(rec: msnerf::gpu::Recorder, kernel: &str) -> Option<usize> {
    let report = rec.submit_and_wait().expect("submit");
    (!report.dispatches.is_empty()).then(|| report.dispatches.iter().filter(|d| d.name == kernel).count())
}

#[test]
fn forward_matches_twin_with_padding() {
    check_forward_with_padding(Reads::Buffer, None);
}

#[test]
fn forward_matches_twin_with_padding_from_texel_buffers() {
    check_forward_with_padding(Reads::Texel, None);
}

#[test]
fn forward_matches_twin_with_padding_in_one_dispatch() {
    check_forward_with_padding(Reads::OneDispatch, None);
}

/// `MSNERF_HASH_ONE_DISPATCH` overrides the default (on GPUs one dispatch for passes of up to 2^20 points, per
/// level on CPU devices).
#[test]
fn one_dispatch_default_follows_the_device_kind() {
    let g = gpu();
    let want = match std::env::var("MSNERF_HASH_ONE_DISPATCH").as_deref() {
        Ok("1") => usize::MAX,
        Ok("0") => 0,
        Ok(v) => panic!("MSNERF_HASH_ONE_DISPATCH={v} is not 0 or 1"),
        Err(_) if g.caps().is_cpu => 0,
        Err(_) => 1 << 20,
    };
    assert_eq!(hashgrid::GPU_ONE_DISPATCH_MAX_POINTS, 1 << 20);
    assert_eq!(hashgrid::default_one_dispatch(&g).expect("default"), want);
    assert_eq!(HashGrid::new(&g, &small()).expect("grid").one_dispatch_max_points(), want);
}

/// The size rule (GPUs by default): a forward or input gradient of at most the grid's limit records one dispatch
/// for all levels, one point more records one per level, and both sizes encode and differentiate as the twin does.
/// The paths share their dispatch names, so the count tells them apart: the test needs timestamps (both target
/// devices have them).
#[test]
fn one_dispatch_follows_the_pass_size() {
    let g = gpu();
    let cfg = small();
    let mut s = setup(&g, &cfg, 8, 17);
    s.grid.set_texel_reads(false);
    let max = 500;
    s.grid.set_one_dispatch_max_points(max);
    let params = ParamSlice { array: &s.params, offset: s.offset };
    let pts = points(&cfg, max + 1, 18, 1e-3);
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
    let width = 12;
    let dy_host = random_params((max + 1) * width, 19, 1.0);
    let dy = GpuBuffer::from_slice(&g, "dy", MemoryCategory::Activations, &dy_host).expect("dy");
    let levels = cfg.levels();
    let host64: Vec<f64> = s.host.iter().map(|&v| v as f64).collect();
    let count = |rec, kernel: &str| {
        submit_and_count(rec, kernel).unwrap_or_else(|| panic!("{}: no timestamps to count {kernel} by", g.caps().name))
    };
    let mut first_dp: Option<Vec<f32>> = None;
    for (n, dispatches) in [(max, 1), (max + 1, cfg.n_levels as usize)] {
        assert_eq!(s.grid.one_dispatch_for(n), dispatches == 1, "{n} points");
        let out =
            GpuBuffer::from_slice(&g, "out", MemoryCategory::Activations, &vec![-9.0f32; n * width]).expect("out");
        let mut rec = g.recorder_timed("fwd", true).expect("recorder");
        let slot = OutputSlot { stride: width, col: 0, pad_to: width, pad_value: 0.0 };
        s.grid.forward(&mut rec, params, &pos, n, &out, slot).expect("fwd");
        assert_eq!(count(rec, "hashgrid_fwd"), dispatches, "forward of {n} points");
        let want: Vec<f32> = pts[..n].iter().flat_map(|p| twin::forward(&levels, 2, &s.host, *p)).collect();
        assert_all_close_f32(&g.download(&out).expect("download"), &want, &format!("forward of {n} points"));
        let dp = GpuBuffer::from_slice(&g, "dp", MemoryCategory::Activations, &vec![f32::NAN; 3 * n]).expect("dp");
        let mut rec = g.recorder_timed("bwd input", true).expect("recorder");
        let dys = RowSlice { buf: &dy, stride: width, col: 0 };
        s.grid.backward_input(&mut rec, params, &pos, n, dys, &dp).expect("bwd input");
        assert_eq!(count(rec, "hashgrid_bwd_input"), dispatches, "input gradient of {n} points");
        let got = g.download(&dp).expect("download");
        // The kernels scale fp32 positions by up to 96 cells (the finest level): a rounding of 1e-5 of a cell in
        // one axis's interpolation weight moves dp by about 1e-3 here, so the f64 twin gets 5e-3; the two paths,
        // which sum the levels in the same order, get the fp32 tolerance against each other.
        for (i, p) in pts[..n].iter().enumerate() {
            let p64 = [p[0] as f64, p[1] as f64, p[2] as f64];
            let d64: Vec<f64> = dy_host[i * width..(i + 1) * width].iter().map(|&v| v as f64).collect();
            let want = twin::backward_input(&levels, 2, &host64, p64, &d64);
            for d in 0..3 {
                let (a, b) = (got[3 * i + d] as f64, want[d]);
                assert!(common::close(a, b, 5e-3, 1e-3), "{n} points: dp[{i}][{d}] {a} vs {b}");
            }
        }
        match &first_dp {
            None => first_dp = Some(got),
            Some(one) => assert_all_close_f32(&got[..3 * max], one, "input gradient per level against one dispatch"),
        }
    }
    s.grid.set_one_dispatch(true);
    assert!(s.grid.one_dispatch_for(usize::MAX), "on: every size");
    s.grid.set_one_dispatch(false);
    assert!(!s.grid.one_dispatch_for(1), "off: no size");
}

/// Coarse-to-fine (`field.coarse_to_fine`): with 2.5 of the 6 levels active, levels 0-1 keep weight 1, level 2
/// gets 0.5 and levels 3-5 encode zeros, in the forward and in both gradients, against the twin's weighted
/// functions (which the finite-difference tests below check), with every read path.
#[test]
fn coarse_to_fine_levels_match_twin() {
    for reads in ALL_READS {
        check_forward_with_padding(reads, Some(2.5));
        check_backward_input(reads, Some(2.5));
    }
    let cfg = small();
    for run in [1, 8] {
        check_backward_params(run, points(&cfg, 3001, 8, 0.0), &[3, 4], 1e-4, Some(2.5));
    }
    // Every level held back but the coarsest; and all of them active again.
    check_forward_with_padding(Reads::Buffer, Some(1.0));
    check_forward_with_padding(Reads::OneDispatch, Some(1.0));
    check_backward_input(Reads::OneDispatch, Some(1.0));
    check_backward_params(1, points(&cfg, 3001, 8, 0.0), &[], 1e-4, Some(6.0));
}

/// The forward against the twin, its tables read as `reads` says; `active`: the grid's coarse-to-fine levels (None:
/// the default, all of them). Rows of 20 floats from column 3: every store one float wide.
fn check_forward_with_padding(reads: Reads, active: Option<f32>) {
    check_forward_in_rows(reads, active, 20, 3);
}

/// The padding columns next to wide stores: rows of 24 floats from column 4, so each level's two features and
/// the last level's padding are stored two floats at a time.
#[test]
fn forward_pads_rows_stored_two_floats_at_a_time() {
    for reads in ALL_READS {
        check_forward_in_rows(reads, None, 24, 4);
    }
}

/// As `check_forward_with_padding`, the 12 features and 4 padding columns at `col` of rows of `stride` floats.
fn check_forward_in_rows(reads: Reads, active: Option<f32>, stride: usize, col: usize) {
    let g = gpu();
    let cfg = small();
    let mut s = setup(&g, &cfg, 24, 5);
    reads.apply(&mut s.grid);
    let weights = set_active(&s.grid, &cfg, active);
    let levels_read = s.grid.texel_levels(ParamSlice { array: &s.params, offset: s.offset }).expect("levels");
    assert_eq!(levels_read, reads.texel_levels(&cfg), "{reads:?}: the texel kernels run");
    let n = 1013; // not a multiple of the 128-wide workgroup
    let pts = points(&cfg, n, 6, 0.0);
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
    let pad_to = 16; // 12 features + 4 padding columns
    let out = GpuBuffer::from_slice(&g, "out", MemoryCategory::Activations, &vec![-9.0f32; n * stride]).expect("out");
    let mut rec = g.recorder_timed("fwd", true).expect("recorder");
    s.grid
        .forward(
            &mut rec,
            ParamSlice { array: &s.params, offset: s.offset },
            &pos,
            n,
            &out,
            OutputSlot { stride, col, pad_to, pad_value: 1.0 },
        )
        .expect("fwd");
    submit_counting(rec, "hashgrid_fwd", reads.dispatches(&cfg), &format!("forward, {reads:?}"));
    let got = g.download(&out).expect("download");
    let levels = cfg.levels();
    let mut want = vec![-9.0f32; n * stride];
    for (i, p) in pts.iter().enumerate() {
        let enc = twin::forward_weighted(&levels, 2, &s.host, *p, &weights);
        want[i * stride + col..i * stride + col + 12].copy_from_slice(&enc);
        want[i * stride + col + 12..i * stride + col + 16].fill(1.0);
    }
    assert_all_close_f32(&got, &want, &format!("hash grid forward, {reads:?} (active levels {active:?})"));
    if let Some(a) = active {
        let held_back = (a.ceil() as usize * 2)..12;
        assert!(
            (0..n).all(|i| got[i * stride + col..i * stride + col + 12][held_back.clone()].iter().all(|&v| v == 0.0)),
            "held-back levels encode zeros"
        );
    }
}

/// Sets the grid's coarse-to-fine levels (None: leaves the default) and returns the twin's level weights.
fn set_active(grid: &HashGrid, cfg: &HashGridConfig, active: Option<f32>) -> Vec<f32> {
    if let Some(a) = active {
        grid.set_active_levels(a);
    }
    assert_eq!(grid.active_levels(), active.unwrap_or(cfg.n_levels as f32));
    twin::level_weights(cfg.n_levels as usize, grid.active_levels())
}

#[test]
fn one_four_and_eight_features_read_texels_as_buffers_do() {
    // Each entry width has its own texel format (R32, R32G32B32A32, two of those): the forward and the input
    // gradient both ways against the twin.
    let g = gpu();
    for f in [1u32, 4, 8] {
        let cfg = HashGridConfig { features_per_level: f, ..small() };
        let width = cfg.n_output();
        let mut s = setup(&g, &cfg, 16, 40 + f as u64);
        let n = 300;
        let pts = points(&cfg, n, 41, 0.0);
        let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
        let levels = cfg.levels();
        let want: Vec<f32> = pts.iter().flat_map(|p| twin::forward(&levels, f as usize, &s.host, *p)).collect();
        for reads in ALL_READS {
            reads.apply(&mut s.grid);
            let out = s.grid.output_buffer(&g, n, width).expect("out");
            let mut rec = g.recorder("fwd").expect("recorder");
            let slot = OutputSlot { stride: width, col: 0, pad_to: width, pad_value: 0.0 };
            let params = ParamSlice { array: &s.params, offset: s.offset };
            s.grid.forward(&mut rec, params, &pos, n, &out, slot).expect("fwd");
            rec.submit_and_wait().expect("submit");
            let got = g.download(&out).expect("download");
            assert_all_close_f32(&got, &want, &format!("forward, {f} features, {reads:?}"));
            let read = s.grid.texel_levels(params).expect("levels");
            assert_eq!(read, reads.texel_levels(&cfg), "{f} features, {reads:?}: the texel kernels run");
            // The input gradient reads the same entries.
            let dy_host = random_params(n * width, 42, 1.0);
            let dy = GpuBuffer::from_slice(&g, "dy", MemoryCategory::Activations, &dy_host).expect("dy");
            let dp = s.grid.output_buffer(&g, n, 3).expect("dp");
            let mut rec = g.recorder("bwd input").expect("recorder");
            let dys = RowSlice { buf: &dy, stride: width, col: 0 };
            s.grid.backward_input(&mut rec, params, &pos, n, dys, &dp).expect("bwd input");
            rec.submit_and_wait().expect("submit");
            let got = g.download(&dp).expect("download");
            let host64: Vec<f64> = s.host.iter().map(|&v| v as f64).collect();
            for (i, p) in pts.iter().enumerate() {
                let p64 = [p[0] as f64, p[1] as f64, p[2] as f64];
                let d64: Vec<f64> = dy_host[i * width..(i + 1) * width].iter().map(|&v| v as f64).collect();
                let want = twin::backward_input(&levels, f as usize, &host64, p64, &d64);
                for d in 0..3 {
                    let (a, b) = (got[3 * i + d] as f64, want[d]);
                    assert!(common::close(a, b, 1e-3, 1e-4), "{f} features, {reads:?}: dp[{i}][{d}] {a} vs {b}");
                }
            }
        }
    }
}

#[test]
fn backward_params_matches_twin_at_99th_percentile() {
    let cfg = small();
    check_backward_params(1, points(&cfg, 3001, 8, 0.0), &[], 1e-4, None);
}

/// Run combining is the default on GPUs and off on CPU devices, where it measured slower (docs/benchmarks.md);
/// `MSNERF_HASH_BWD_RUN` overrides both.
#[test]
fn backward_run_default_follows_the_device_kind() {
    let g = gpu();
    let want = match std::env::var("MSNERF_HASH_BWD_RUN") {
        Ok(v) => v.trim().parse().expect("MSNERF_HASH_BWD_RUN is a number"),
        Err(_) if g.caps().is_cpu => 1,
        Err(_) => hashgrid::GPU_BACKWARD_RUN,
    };
    assert_eq!(hashgrid::default_backward_run(&g).expect("default"), want);
}

/// The parameter gradient with its texel prefetch (`hashgrid_bwd_prefetch`: the corners' gradient entries gathered
/// before the atomics) and without, on random and on ray-ordered points with masked ones, coarse-to-fine levels
/// included: the same sums.
#[test]
fn backward_params_with_and_without_the_texel_prefetch_match_twin() {
    let cfg = small();
    let g = gpu();
    let mut grid = HashGrid::with_backward_run(&g, &cfg, 1).expect("grid");
    grid.set_texel_reads(true);
    let params = LargeArray::<f32>::new(&g, "grads", cfg.n_params(), MemoryCategory::Gradients).expect("grads");
    let levels = grid.texel_levels(ParamSlice { array: &params, offset: 0 }).expect("levels");
    assert_eq!(levels, cfg.n_levels as usize, "every level's gradient table has a texel view: the prefetch runs");
    for texel in [false, true] {
        check_backward_params_reading(Some(texel), 1, points(&cfg, 3001, 8, 0.0), &[], 1e-4, None);
        check_backward_params_reading(Some(texel), 1, ray_points(), &[5, 6, 7, 8, 9, 100, 2999], 3e-4, Some(4.5));
    }
}

/// 3001 points in runs of 24 along short random rays (ray-ordered, as training produces them).
fn ray_points() -> Vec<[f32; 3]> {
    let mut pts = Vec::new();
    let mut r = common::rng(21);
    while pts.len() < 3001 {
        let o: [f32; 3] = std::array::from_fn(|_| r.random_range(0.3f32..0.7));
        let d: [f32; 3] = std::array::from_fn(|_| r.random_range(-0.2f32..0.2));
        for i in 0..24 {
            pts.push(std::array::from_fn(|k| (o[k] + d[k] * i as f32 / 24.0).clamp(0.0, 1.0)));
        }
    }
    pts.truncate(3001);
    pts
}

#[test]
fn backward_params_with_run_combining_matches_twin() {
    // hashgrid_bwd with RUN = 8 on ray-ordered points (runs of equal coarse cells), n not a multiple of 8, and
    // masked-out points (zero dL/dy) inside runs: the same sums as one point per invocation.
    let pts = ray_points();
    let masked = [5, 6, 7, 8, 9, 100, 2999];
    // Ray-ordered points pile hundreds of contributions onto the coarse levels' entries: fp32 sums of that length
    // (in either kernel) sit at a 99th-percentile error of about 1.2e-4 here, hence 3e-4.
    let one = check_backward_params(1, pts.clone(), &masked, 3e-4, None);
    let eight = check_backward_params(8, pts, &masked, 3e-4, None);
    assert!(eight <= 2.0 * one + 1e-5, "run combining adds rounding: p99 {eight:e} against {one:e}");
}

/// The parameter gradient of `pts` (with dL/dy zeroed for the points in `masked`) against the twin; returns the
/// 99th-percentile relative error after asserting it is below `tol`; `active` as in `check_forward_with_padding`.
///
/// One point per invocation (`run` 1) runs `hashgrid_bwd_prefetch` where the grid reads texels (the default on CPU
/// devices) and `hashgrid_bwd` where it does not; `MSNERF_HASH_TEXEL` sets it for every test but
/// `backward_params_with_and_without_the_texel_prefetch_match_twin`, which runs both.
fn check_backward_params(run: u32, pts: Vec<[f32; 3]>, masked: &[usize], tol: f64, active: Option<f32>) -> f64 {
    check_backward_params_reading(None, run, pts, masked, tol, active)
}

/// As `check_backward_params`, with texel reads (and so the prefetch) set when `texel` is given.
fn check_backward_params_reading(
    texel: Option<bool>,
    run: u32,
    pts: Vec<[f32; 3]>,
    masked: &[usize],
    tol: f64,
    active: Option<f32>,
) -> f64 {
    let g = gpu();
    let cfg = small();
    let mut grid = HashGrid::with_backward_run(&g, &cfg, run).expect("grid");
    if let Some(t) = texel {
        grid.set_texel_reads(t);
    }
    let weights: Vec<f64> = set_active(&grid, &cfg, active).iter().map(|&w| w as f64).collect();
    let n = pts.len();
    let mut dy_host = random_params(n * 12, 9, 1.0);
    for &m in masked {
        dy_host[m * 12..(m + 1) * 12].fill(0.0);
    }
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
    let dy = GpuBuffer::from_slice(&g, "dy", MemoryCategory::Activations, &dy_host).expect("dy");
    let grads = LargeArray::<f32>::new(&g, "grads", cfg.n_params(), MemoryCategory::Gradients).expect("grads");
    let mut rec = g.recorder("bwd").expect("recorder");
    for c in grads.chunks() {
        ops::fill(&mut rec, c, 0.0f32, 0, c.len()).expect("zero");
    }
    grid.backward_params(
        &mut rec,
        ParamSlice { array: &grads, offset: 0 },
        &pos,
        n,
        RowSlice { buf: &dy, stride: 12, col: 0 },
    )
    .expect("bwd");
    rec.submit_and_wait().expect("submit");
    let got = grads.download(&g).expect("download");
    let levels = cfg.levels();
    let mut want = vec![0.0f64; cfg.n_params()];
    for (i, p) in pts.iter().enumerate() {
        let p64 = [p[0] as f64, p[1] as f64, p[2] as f64];
        let d64: Vec<f64> = dy_host[i * 12..(i + 1) * 12].iter().map(|&v| v as f64).collect();
        twin::backward_params_weighted(&levels, 2, p64, &d64, &mut want, &weights);
    }
    let touched: Vec<usize> = (0..want.len()).filter(|&i| want[i] != 0.0).collect();
    assert!(touched.len() > 1000, "the test must touch many entries");
    if let Some(a) = active.filter(|&a| a < cfg.n_levels as f32) {
        // The held-back levels' entries (from the first level past `a` on) get nothing.
        let first = levels[a.ceil() as usize].offset as usize * 2;
        assert!(want[first..].iter().all(|&v| v == 0.0) && got[first..].iter().all(|&v| v == 0.0), "held back");
    }
    let mut rel: Vec<f64> = touched.iter().map(|&i| (got[i] as f64 - want[i]).abs() / (want[i].abs() + 1e-3)).collect();
    rel.sort_by(f64::total_cmp);
    let p99 = rel[(rel.len() * 99) / 100];
    assert!(p99 < tol, "run {run}: 99th percentile relative error {p99:e}");
    let worst = rel.last().copied().unwrap_or(0.0);
    assert!(worst < 1e-2, "run {run}: worst relative error {worst:e}");
    assert!((0..want.len()).filter(|&i| want[i] == 0.0).all(|i| got[i] == 0.0), "untouched entries stay zero");
    p99
}

#[test]
fn backward_input_matches_twin_and_finite_differences() {
    check_backward_input(Reads::Buffer, None);
}

#[test]
fn backward_input_matches_twin_and_finite_differences_from_texel_buffers() {
    check_backward_input(Reads::Texel, None);
}

#[test]
fn backward_input_matches_twin_and_finite_differences_in_one_dispatch() {
    check_backward_input(Reads::OneDispatch, None);
}

/// The input gradient against the twin and central differences (of the weighted forward with `active` levels, as
/// in `check_forward_with_padding`), its tables read as `reads` says.
fn check_backward_input(reads: Reads, active: Option<f32>) {
    let g = gpu();
    let cfg = small();
    let mut s = setup(&g, &cfg, 8, 11);
    reads.apply(&mut s.grid);
    let weights: Vec<f64> = set_active(&s.grid, &cfg, active).iter().map(|&w| w as f64).collect();
    let levels_read = s.grid.texel_levels(ParamSlice { array: &s.params, offset: s.offset }).expect("levels");
    assert_eq!(levels_read, reads.texel_levels(&cfg), "{reads:?}: the texel kernels run");
    let n = 300;
    let pts = points(&cfg, n, 12, 0.05);
    let dy_host = random_params(n * 12, 13, 1.0);
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
    let dy = GpuBuffer::from_slice(&g, "dy", MemoryCategory::Activations, &dy_host).expect("dy");
    let dp = GpuBuffer::<f32>::new(&g, &BufferDesc { name: "dp", len: 3 * n, category: MemoryCategory::Activations })
        .expect("dp");
    // dp starts as NaN: every kernel shape must write it, not add to it.
    g.upload(&dp, 0, &vec![f32::NAN; 3 * n]).expect("poison dp");
    let mut rec = g.recorder_timed("bwd input", true).expect("recorder");
    s.grid
        .backward_input(
            &mut rec,
            ParamSlice { array: &s.params, offset: s.offset },
            &pos,
            n,
            RowSlice { buf: &dy, stride: 12, col: 0 },
            &dp,
        )
        .expect("bwd input");
    submit_counting(rec, "hashgrid_bwd_input", reads.dispatches(&cfg), &format!("input gradient, {reads:?}"));
    let got = g.download(&dp).expect("download");
    let levels = cfg.levels();
    let host64: Vec<f64> = s.host.iter().map(|&v| v as f64).collect();
    let mut want = Vec::with_capacity(3 * n);
    for (i, p) in pts.iter().enumerate() {
        let p64 = [p[0] as f64, p[1] as f64, p[2] as f64];
        let d64: Vec<f64> = dy_host[i * 12..(i + 1) * 12].iter().map(|&v| v as f64).collect();
        let analytic = twin::backward_input_weighted(&levels, 2, &host64, p64, &d64, &weights);
        // Central differences of L = <dy, forward(p)> in f64.
        let loss = |q: [f64; 3]| {
            twin::forward_weighted(&levels, 2, &host64, q, &weights).iter().zip(&d64).map(|(a, b)| a * b).sum::<f64>()
        };
        for d in 0..3 {
            let h = 1e-7;
            let (mut a, mut b) = (p64, p64);
            a[d] += h;
            b[d] -= h;
            let fd = (loss(a) - loss(b)) / (2.0 * h);
            assert!(common::close(analytic[d], fd, 1e-5, 1e-5), "point {i} axis {d}: analytic {} fd {fd}", analytic[d]);
            want.push(analytic[d] as f32);
        }
    }
    // The input gradient sums over levels with large scales: allow the fp32 rounding of that sum.
    for i in 0..got.len() {
        assert!(
            common::close(got[i] as f64, want[i] as f64, 1e-3, 1e-4),
            "{reads:?} dp[{i}]: {} vs {}",
            got[i],
            want[i]
        );
    }
}

#[test]
fn parameter_gradient_matches_finite_differences() {
    // d<dy, forward(p)>/d theta_j by central differences in f64 equals the twin's backward, which the GPU matches.
    let cfg = small();
    let levels = cfg.levels();
    let theta: Vec<f64> = random_params(cfg.n_params(), 14, 1.0).iter().map(|&v| v as f64).collect();
    let pts = points(&cfg, 5, 15, 0.05);
    let dy: Vec<f64> = random_params(12, 16, 1.0).iter().map(|&v| v as f64).collect();
    // All levels, and coarse-to-fine weights (2.5 active levels) against the weighted forward.
    for (p, active) in pts.iter().zip([6.0, 2.5, 6.0, 3.25, 4.0]) {
        let weights = twin::level_weights(levels.len(), active);
        let p64 = [p[0] as f64, p[1] as f64, p[2] as f64];
        let mut grad = vec![0.0; theta.len()];
        twin::backward_params_weighted(&levels, 2, p64, &dy, &mut grad, &weights);
        let nz: Vec<usize> = (0..grad.len()).filter(|&j| grad[j] != 0.0).take(40).collect();
        assert!(!nz.is_empty());
        for &j in &nz {
            let mut tp = theta.clone();
            let mut tm = theta.clone();
            tp[j] += 1e-6;
            tm[j] -= 1e-6;
            let l = |t: &[f64]| {
                twin::forward_weighted(&levels, 2, t, p64, &weights).iter().zip(&dy).map(|(a, b)| a * b).sum::<f64>()
            };
            let fd = (l(&tp) - l(&tm)) / 2e-6;
            assert!(common::close(grad[j], fd, 1e-8, 1e-6), "theta[{j}]: {} vs {fd}", grad[j]);
        }
    }
}

#[test]
fn table1_grid_of_256_mib_works_on_every_device() {
    check_table1_grid(Reads::Buffer);
}

#[test]
fn table1_grid_of_256_mib_works_on_every_device_from_texel_buffers() {
    check_table1_grid(Reads::Texel);
}

#[test]
fn table1_grid_of_256_mib_works_on_every_device_in_one_dispatch() {
    check_table1_grid(Reads::OneDispatch);
}

/// Table 1's grid over two chunks: with texel reads the levels inside one chunk use texels, the one across chunks
/// the device address; in one dispatch every entry's chunk is looked up in the chunk table.
fn check_table1_grid(reads: Reads) {
    // Multispectral-NeRF Table 1: 16 levels x 2 features x 2^21 entries: 256 MiB of fp32, more than one binding.
    let g = gpu();
    let cfg = HashGridConfig {
        n_levels: 16,
        features_per_level: 2,
        log2_hashmap_size: 21,
        base_resolution: 16,
        max_resolution: 8192,
    };
    let n_params = cfg.n_params();
    assert!(n_params * 4 > g.caps().max_storage_buffer_range as usize || g.caps().max_storage_buffer_range > 1 << 28);
    let mut s = setup(&g, &cfg, 0, 21);
    reads.apply(&mut s.grid);
    let levels_read = s.grid.texel_levels(ParamSlice { array: &s.params, offset: s.offset }).expect("levels");
    let texel = reads == Reads::Texel;
    assert!(if texel { levels_read > 0 } else { levels_read == 0 }, "{levels_read} levels read as texels");
    assert!(s.params.chunks().len() >= 2 || g.caps().max_storage_buffer_range as usize >= n_params * 4);
    let n = 257;
    let pts = points(&cfg, n, 22, 0.0);
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat(&pts)).expect("pos");
    let out = s.grid.output_buffer(&g, n, 32).expect("out");
    let mut rec = g.recorder("table1").expect("recorder");
    s.grid
        .forward(
            &mut rec,
            ParamSlice { array: &s.params, offset: 0 },
            &pos,
            n,
            &out,
            OutputSlot { stride: 32, col: 0, pad_to: 32, pad_value: 0.0 },
        )
        .expect("fwd");
    rec.submit_and_wait().expect("submit");
    let got = g.download(&out).expect("download");
    let levels = cfg.levels();
    let want: Vec<f32> = pts.iter().flat_map(|p| twin::forward(&levels, 2, &s.host, *p)).collect();
    assert_all_close_f32(&got, &want, &format!("Table 1 grid forward, {reads:?}"));
    // The input gradient reads the same entries, the level across the chunk boundary included. At scales up to
    // 8192 its fp32 cell fractions carry errors of ~5e-4 cells, so it is compared with the per-level device-address
    // kernel (which the small grids' tests hold to the twin and to finite differences), not with the f64 twin.
    if reads != Reads::Buffer {
        let dy_host = random_params(n * 32, 23, 1.0);
        let dy = GpuBuffer::from_slice(&g, "dy", MemoryCategory::Activations, &dy_host).expect("dy");
        let mut dps = Vec::new();
        for mode in [reads, Reads::Buffer] {
            mode.apply(&mut s.grid);
            let dp = s.grid.output_buffer(&g, n, 3).expect("dp");
            let mut rec = g.recorder("table1 input gradient").expect("recorder");
            let (params, dys) = (ParamSlice { array: &s.params, offset: 0 }, RowSlice { buf: &dy, stride: 32, col: 0 });
            s.grid.backward_input(&mut rec, params, &pos, n, dys, &dp).expect("bwd input");
            rec.submit_and_wait().expect("submit");
            dps.push(g.download(&dp).expect("download"));
        }
        assert!(dps[0].iter().all(|v| v.is_finite()) && dps[0].iter().any(|&v| v.abs() > 1.0), "a real gradient");
        for (i, (a, b)) in dps[0].iter().zip(&dps[1]).enumerate() {
            assert!(common::close(*a as f64, *b as f64, 1e-5, 1e-4), "Table 1, {reads:?}: dp[{i}] {a} vs {b}");
        }
    }
}
