//! Outside oracles: msnerf's PDF resampler, weights, interlevel and distortion losses (and their backward) against
//! nerfstudio 1.1.5's own functions, from the fixtures in `tests/fixtures/nerfstudio/` written once by
//! `tools/fixtures/nerfstudio_fixtures.py` (which calls `PDFSampler`, `ProposalNetworkSampler`,
//! `RaySamples.get_weights`, `interlevel_loss`/`lossfun_outer`, `distortion_loss`/`lossfun_distortion` and torch
//! autograd in float64). A missing or unreadable fixture fails the test.
//!
//! How the quantities map (docs/design/testing.md; spec/nerfacto.md §2.7, §2.12):
//! - PDF: nerfstudio's eval-mode `PDFSampler(include_original=False, histogram_padding=0.01)` fed
//!   `torch.pow(w, anneal)` (ProposalNetworkSampler's line) = msnerf's `pdf_resample(.., anneal, u, jitter=false)`.
//! - interlevel: nerfstudio's loss is the mean over rays and NeRF samples of `lossfun_outer`, summed over proposal
//!   levels; msnerf returns per ray `norm * sum_i` with `norm = mult / (rays * N)`, so with mult = 1 the per-ray
//!   losses sum to nerfstudio's loss and dL/draw is the same gradient.
//! - distortion: nerfstudio's loss is the mean over rays of `lossfun_distortion` (O(N^2) double sum); msnerf's
//!   composite gives per ray `dist_norm * ray_weight * L` (O(N) prefix sums, needs sorted midpoints), so
//!   `dist_norm = 1 / rays` (mult 1, ray weight 1) sums to nerfstudio's loss. The colour loss is switched off
//!   (rgb_norm = 0) so the composite's dL/draw is the distortion's alone.
//! - weights: nerfstudio's `1 - exp(-tau)` cancels for tau << 1 (absolute error up to 2^-52, so relative error up
//!   to 100 % at tau ~ 1e-16), msnerf's `-expm1(-tau)` does not (an intentional difference, docs/stability.md):
//!   weights are compared with an absolute floor of 1e-15, and the losses and gradients built on them within
//!   nerfstudio's rounding propagated (`nerfstudio_*_floor`; negligible except in the near-zero cases).
//! - Not compared (msnerf has no such mode): `include_original=True`, other histogram paddings, per-sample jitter;
//!   training-mode stratified sampling (random numbers) is covered by the twin-vs-kernel tests.
//!
//! Tolerances. f64 twin: |a - b| <= 1e-9 |b| + floor, the floor 1e-12 for edges in [0, 1], 1e-15 for weights,
//! 1e-9 max|b| of the array for gradients (sums with cancellation), plus the propagated floors above. Measured
//! (MSNERF_ORACLE_REPORT=1 prints each check's worst error as a fraction of its tolerance): edges and losses agree
//! to ~1e-15 relative, gradients to ~1e-13 of the array's max. Each twin test also checks that a 1e-7 change of
//! an input breaks its tolerance. f32 kernels (lavapipe): stated at the constants below, from the f32 error of the
//! sums involved; measured worst errors are 0.4x the tolerance for weights and edges, under 0.1x for losses and
//! gradients, and each kernel test checks that a 1e-4 change of an input (1e-3 of a stratum for the resampler)
//! breaks its tolerance.

use crate::common;
use common::gpu;
use msnerf::gpu::{Context, GpuBuffer, MemoryCategory};
use msnerf::nerf::buffers::RAY_OUT_FIXED;
use msnerf::nerf::kernels::{
    BackgroundMode, CompositeBuffers, CompositeParams, Geometry, InterlevelBuffers, Jitter, RayBuffers, RenderKernels,
};
use msnerf::reference::render as tw;
use serde::Deserialize;

// ------------------------------------------------------------------------------------------------------- fixtures

#[derive(Deserialize)]
struct Header {
    generator: String,
    nerfstudio_version: String,
    torch_version: String,
    near: f64,
    far: f64,
    density_scale: f64,
}

#[derive(Deserialize)]
struct PdfCase {
    name: String,
    rays: usize,
    n: usize,
    m: usize,
    anneal: f64,
    edges: Vec<f64>,
    weights: Vec<f64>,
    new_edges: Vec<f64>,
}

#[derive(Deserialize)]
struct InterlevelCase {
    name: String,
    rays: usize,
    n_nerf: usize,
    n_prop: usize,
    nerf_edges: Vec<f64>,
    nerf_weights: Vec<f64>,
    prop_edges: Vec<f64>,
    prop_raw: Vec<f64>,
    prop_weights: Vec<f64>,
    per_ray_outer_sum: Vec<f64>,
    loss: f64,
    d_loss_d_prop_raw: Vec<f64>,
}

#[derive(Deserialize)]
struct DistortionCase {
    name: String,
    rays: usize,
    n: usize,
    edges: Vec<f64>,
    raw: Vec<f64>,
    weights: Vec<f64>,
    per_ray: Vec<f64>,
    loss: f64,
    d_loss_d_raw: Vec<f64>,
}

#[derive(Deserialize)]
struct Cases<C> {
    header: Header,
    cases: Vec<C>,
}

#[derive(Deserialize)]
struct ChainLevel {
    n: usize,
    raw: Vec<f64>,
    edges: Vec<f64>,
    t_edges: Vec<f64>,
    weights: Vec<f64>,
}

#[derive(Deserialize)]
struct Chain {
    header: Header,
    rays: usize,
    anneal: f64,
    levels: Vec<ChainLevel>,
    interlevel_loss: f64,
    distortion_loss: f64,
}

/// Reads and parses `tests/fixtures/nerfstudio/NAME`; panics (fails the test) when it is missing or malformed.
fn load<T: serde::de::DeserializeOwned>(name: &str) -> T {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/nerfstudio").join(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; the nerfstudio fixtures are committed: regenerate with tools/fixtures/nerfstudio_fixtures.py",
            path.display()
        )
    });
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn check_header(h: &Header) {
    assert_eq!(h.generator, "tools/fixtures/nerfstudio_fixtures.py");
    assert_eq!(h.nerfstudio_version, "1.1.5", "fixtures from another nerfstudio (torch {})", h.torch_version);
    assert_eq!((h.near as f32 as f64, h.far, h.density_scale), (h.near, 1000.0, 0.01));
}

/// The f32 inputs (written as their shortest f32 decimal) as the f32 values the generator used.
fn f32s(v: &[f64]) -> Vec<f32> {
    v.iter()
        .map(|&x| {
            let f = x as f32;
            assert!((f as f64 - x).abs() <= 1e-7 * x.abs(), "{x} is not an f32 input");
            f
        })
        .collect()
}

/// The f32 inputs exactly, as f64.
fn inputs(v: &[f64]) -> Vec<f64> {
    f32s(v).into_iter().map(f64::from).collect()
}

fn widen(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

// ------------------------------------------------------------------------------------------------------ tolerances

/// |got - want| <= rel |want| + abs + of_max max|want| (the max over `want`).
#[derive(Copy, Clone, Debug)]
struct Tol {
    rel: f64,
    abs: f64,
    of_max: f64,
}

const EDGES: Tol = Tol { rel: 1e-9, abs: 1e-12, of_max: 0.0 };
const WEIGHTS: Tol = Tol { rel: 1e-9, abs: 1e-15, of_max: 0.0 };
const LOSS: Tol = Tol { rel: 1e-9, abs: 0.0, of_max: 0.0 };
const GRAD: Tol = Tol { rel: 1e-9, abs: 0.0, of_max: 1e-9 };

/// The worst |got - want| / bound over the slices (> 1: out of tolerance), and its index; `floor` adds a per-element
/// absolute term.
fn worst(got: &[f64], want: &[f64], t: Tol, floor: Option<&[f64]>) -> (f64, usize) {
    assert_eq!(got.len(), want.len(), "lengths differ");
    let m = want.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let mut w = (0.0, 0);
    for (i, (&a, &b)) in got.iter().zip(want).enumerate() {
        let bound = t.rel * b.abs() + t.abs + t.of_max * m + floor.map_or(0.0, |f| f[i]);
        let diff = (a - b).abs();
        let r = if !a.is_finite() || (diff > 0.0 && bound == 0.0) {
            f64::INFINITY
        } else if diff == 0.0 {
            0.0
        } else {
            diff / bound
        };
        if r > w.0 {
            w = (r, i);
        }
    }
    w
}

fn assert_close(got: &[f64], want: &[f64], t: Tol, what: &str) {
    assert_close_floor(got, want, t, None, what)
}

fn assert_close_floor(got: &[f64], want: &[f64], t: Tol, floor: Option<&[f64]>, what: &str) {
    let (r, i) = worst(got, want, t, floor);
    if std::env::var_os("MSNERF_ORACLE_REPORT").is_some() {
        eprintln!("{what}: worst {r:.3e} of the tolerance (at {i}: got {:e} want {:e})", got[i], want[i]);
    }
    assert!(
        r <= 1.0,
        "{what}[{i}]: got {:e} want {:e} (|diff| {:e}, {r:.3}x the tolerance {t:?})",
        got[i],
        want[i],
        (got[i] - want[i]).abs()
    );
}

/// A 1e-7 change of an input must break the tolerance (the comparison can fail).
fn assert_sensitive(got: &[f64], want: &[f64], t: Tol, what: &str) {
    assert!(
        worst(got, want, t, None).0 > 1.0,
        "{what}: a perturbed input still passes: the tolerance {t:?} is too loose"
    );
}

fn rows<T>(v: &[T], width: usize) -> std::slice::Chunks<'_, T> {
    assert_eq!(v.len() % width, 0);
    v.chunks(width)
}

/// The fixtures' rays in msnerf's terms: contraction on (no sample masked; the hash inputs play no part).
fn geom(h: &Header) -> tw::RayGeom<f64> {
    tw::RayGeom { origin: [0.0; 3], dir: [0.0, 0.0, 1.0], near: h.near, far: h.far, contraction: true }
}

fn geometry(h: &Header) -> Geometry {
    Geometry { near: h.near as f32, far: h.far as f32, contraction: true }
}

// --------------------------------------------------------------------------------------------------- CPU twins (f64)

#[test]
fn pdf_resample_twin_matches_nerfstudio_pdf_sampler() {
    let fx: Cases<PdfCase> = load("pdf_sampler.json");
    check_header(&fx.header);
    assert!(fx.cases.len() >= 6);
    for c in &fx.cases {
        let (edges, weights) = (inputs(&c.edges), inputs(&c.weights));
        let mut got = Vec::new();
        let mut nudged = Vec::new();
        for (e, w) in rows(&edges, c.n + 1).zip(rows(&weights, c.n)) {
            got.extend(tw::pdf_resample(e, w, c.m, c.anneal, 0.5, false));
            // Control: the eval-mode u_k = (k + 0.5)/(m + 1) moved by 1e-7 of a stratum.
            nudged.extend(tw::pdf_resample(e, w, c.m, c.anneal, 0.5 + 1e-7, true));
        }
        assert_eq!(got.len(), c.rays * (c.m + 1), "{}", c.name);
        assert_close(&got, &c.new_edges, EDGES, &format!("{}: new edges", c.name));
        assert_sensitive(&nudged, &c.new_edges, EDGES, &c.name);
    }
}

#[test]
fn weights_and_interlevel_twin_match_nerfstudio_interlevel_loss() {
    let fx: Cases<InterlevelCase> = load("interlevel.json");
    check_header(&fx.header);
    let g = geom(&fx.header);
    let mut with_loss = 0;
    for c in &fx.cases {
        let (big_n, n) = (c.n_nerf, c.n_prop);
        let norm = 1.0 / (c.rays * big_n) as f64;
        let (ne, nw, pe, pr) =
            (inputs(&c.nerf_edges), inputs(&c.nerf_weights), inputs(&c.prop_edges), inputs(&c.prop_raw));
        let (mut wp, mut per_ray, mut grad, mut nudged) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut loss_floor, mut grad_floor) = (Vec::new(), Vec::new());
        for r in 0..c.rays {
            let (nei, nwi) = (&ne[r * (big_n + 1)..(r + 1) * (big_n + 1)], &nw[r * big_n..(r + 1) * big_n]);
            let (pei, pri) = (&pe[r * (n + 1)..(r + 1) * (n + 1)], &pr[r * n..(r + 1) * n]);
            wp.extend(tw::weights(&g, pei, pri, 0.01));
            let (l, d) = tw::interlevel(&g, nei, nwi, pei, pri, 0.01, norm);
            per_ray.push(l / norm);
            grad.extend(d);
            let (lf, gf) = nerfstudio_interlevel_floor(&g, pei, pri, nwi, norm);
            loss_floor.push(lf);
            grad_floor.extend(gf);
            // Control: the NeRF weights 1e-7 larger.
            let nw2: Vec<f64> = nwi.iter().map(|&v| v * (1.0 + 1e-7)).collect();
            nudged.push(tw::interlevel(&g, nei, &nw2, pei, pri, 0.01, norm).0 / norm);
        }
        let what = |q: &str| format!("{}: {q}", c.name);
        assert_close(&wp, &c.prop_weights, WEIGHTS, &what("proposal weights"));
        assert_close_floor(&per_ray, &c.per_ray_outer_sum, LOSS, Some(&loss_floor), &what("per-ray loss"));
        let total: f64 = per_ray.iter().sum::<f64>() * norm;
        let floor = loss_floor.iter().sum::<f64>() * norm;
        assert_close_floor(&[total], &[c.loss], LOSS, Some(&[floor]), &what("interlevel_loss"));
        assert_close_floor(&grad, &c.d_loss_d_prop_raw, GRAD, Some(&grad_floor), &what("dL/draw"));
        if c.loss > 1e-6 {
            with_loss += 1;
            assert_sensitive(&nudged, &c.per_ray_outer_sum, LOSS, &c.name);
            assert!(grad.iter().any(|&v| v != 0.0), "{}: the case must have a gradient", c.name);
        }
    }
    assert!(with_loss >= 4, "the fixture must exercise the loss");
}

/// tau'_k = delta_k 0.01 exp(clamp(raw_k, -15, 15)) of each sample: dL/draw_k = tau'_k dL/dsigma_k / delta_k.
fn tau_prime(g: &tw::RayGeom<f64>, edges: &[f64], raw: &[f64]) -> Vec<f64> {
    edges.windows(2).zip(raw).map(|(e, &x)| (g.t(e[1]) - g.t(e[0])) * 0.01 * x.clamp(-15.0, 15.0).exp()).collect()
}

/// How far nerfstudio's own interlevel loss (per ray, before the mean) and its dL/draw can be from exact: its
/// proposal weights carry an absolute error up to 2 eps each (1 - exp(-tau), see below), so w_outer (a difference
/// of cumsums) up to 3 n eps. Loss term i moves by at most 2 w_i / (w_i + 1e-7) times that; dL/dwp_j by at most
/// norm sum_i 2 (3 n eps) / (w_i + 1e-7); dL/draw_k = tau'_k (g_k T - sum_{j>k} g_j w_j) by tau'_k (2 dg + 2 n eps
/// g_max). Negligible (< 1e-12 relative) unless the weights are near zero.
fn nerfstudio_interlevel_floor(
    g: &tw::RayGeom<f64>,
    prop_edges: &[f64],
    prop_raw: &[f64],
    nerf_w: &[f64],
    norm: f64,
) -> (f64, Vec<f64>) {
    let (n, eps) = (prop_raw.len() as f64, f64::EPSILON);
    let outer = 3.0 * n * eps;
    let loss = nerf_w.iter().map(|&w| 2.0 * w / (w + 1e-7) * outer).sum();
    let dg: f64 = norm * nerf_w.iter().map(|&w| 2.0 * outer / (w + 1e-7)).sum::<f64>();
    let g_max: f64 = norm * nerf_w.iter().map(|&w| 2.0 * w / (w + 1e-7)).sum::<f64>();
    (loss, tau_prime(g, prop_edges, prop_raw).into_iter().map(|t| t * (2.0 * dg + 2.0 * n * eps * g_max)).collect())
}

/// How far nerfstudio's own distortion loss (per ray) and its dL/draw (per sample, of the mean over `rays`) can be
/// from exact: its weights `(1 - exp(-tau)) T` carry an absolute error up to eps = 2^-52 each (the cancellation
/// msnerf's `-expm1(-tau)` avoids). With m in [0, 1], dL/dw_i <= (8/3) A (A = sum of the weights), so the loss is
/// off by at most (8/3) n eps A; dL/dw_i is off by at most 3 n eps, so dL/dsigma_k by delta_k 9 n eps, and
/// dL/draw_k by tau'_k 9 n eps / rays with tau'_k = delta_k 0.01 exp(clamp(raw_k, -15, 15)) (trunc_exp's backward).
/// Negligible (< 1e-12 relative) unless the weights are near zero, where nerfstudio's values are rounding noise.
fn nerfstudio_distortion_floor(
    g: &tw::RayGeom<f64>,
    edges: &[f64],
    raw: &[f64],
    ns_weights: &[f64],
    rays: usize,
) -> (f64, Vec<f64>) {
    let (n, eps) = (raw.len() as f64, f64::EPSILON);
    let a: f64 = ns_weights.iter().sum();
    let grad = tau_prime(g, edges, raw).into_iter().map(|t| t * 9.0 * n * eps / rays as f64).collect();
    (8.0 / 3.0 * n * eps * a, grad)
}

/// msnerf's composite of one ray with only the distortion loss on (no colour loss, no depth), mult 1.
fn distortion_in<'a>(
    g: tw::RayGeom<f64>,
    edges: &'a [f64],
    raw: &'a [f64],
    zeros: &'a [f64],
    rays: usize,
) -> tw::CompositeIn<'a, f64> {
    tw::CompositeIn {
        geom: g,
        edges,
        raw,
        colours: zeros,
        target: &zeros[..1],
        ray_weight: 1.0,
        band_weights: &[1.0],
        density_scale: 0.01,
        background: tw::Background::Constant(0.0),
        rgb_norm: 0.0,
        dist_norm: 1.0 / rays as f64,
        grad_scaling: false,
        depth: None,
    }
}

#[test]
fn weights_and_distortion_twin_match_nerfstudio_distortion_loss() {
    let fx: Cases<DistortionCase> = load("distortion.json");
    check_header(&fx.header);
    let g = geom(&fx.header);
    for c in &fx.cases {
        let n = c.n;
        let (edges, raw) = (inputs(&c.edges), inputs(&c.raw));
        let zeros = vec![0.0; n];
        let (mut w, mut per_ray, mut grad, mut nudged) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut loss_floor, mut grad_floor) = (Vec::new(), Vec::new());
        for r in 0..c.rays {
            let (e, x) = (&edges[r * (n + 1)..(r + 1) * (n + 1)], &raw[r * n..(r + 1) * n]);
            let (lf, gf) = nerfstudio_distortion_floor(&g, e, x, &c.weights[r * n..(r + 1) * n], c.rays);
            loss_floor.push(lf);
            grad_floor.extend(gf);
            let t = tw::composite(&distortion_in(g, e, x, &zeros, c.rays));
            assert_eq!(t.loss_rgb, 0.0);
            w.extend(t.weights);
            per_ray.push(t.loss_dist * c.rays as f64);
            grad.extend(t.d_raw);
            let e2: Vec<f64> = e.iter().map(|&s| s * (1.0 - 1e-7)).collect(); // control: edges 1e-7 closer to 0
            nudged.push(tw::composite(&distortion_in(g, &e2, x, &zeros, c.rays)).loss_dist * c.rays as f64);
        }
        let what = |q: &str| format!("{}: {q}", c.name);
        assert_close(&w, &c.weights, WEIGHTS, &what("weights"));
        assert_close_floor(&per_ray, &c.per_ray, LOSS, Some(&loss_floor), &what("per-ray distortion"));
        let floor = loss_floor.iter().sum::<f64>() / c.rays as f64;
        let total = per_ray.iter().sum::<f64>() / c.rays as f64;
        assert_close_floor(&[total], &[c.loss], LOSS, Some(&[floor]), &what("distortion_loss"));
        assert_close_floor(&grad, &c.d_loss_d_raw, GRAD, Some(&grad_floor), &what("dL/draw"));
        if c.per_ray.iter().all(|&l| l > 1e-6) {
            assert_sensitive(&nudged, &c.per_ray, LOSS, &c.name);
        }
    }
}

#[test]
fn sampling_chain_twin_matches_nerfstudio_proposal_network_sampler() {
    let ch: Chain = load("proposal_chain.json");
    check_header(&ch.header);
    let g = geom(&ch.header);
    assert_eq!(ch.levels.len(), 3, "two proposal levels and the NeRF level");
    let last = &ch.levels[2];
    let mut interlevel = 0.0;
    for (l, lv) in ch.levels.iter().enumerate() {
        let (n, raw) = (lv.n, inputs(&lv.raw));
        let mut t_edges = Vec::new();
        let mut w = Vec::new();
        for (r, e) in rows(&lv.edges, n + 1).enumerate() {
            if l == 0 {
                // nerfstudio's UniformLinDispPiecewiseSampler in eval mode = msnerf's unjittered initial edges.
                assert_close(&tw::initial_edges(n, 0.5, false), e, EDGES, "level 0 edges");
            } else {
                // Resampling from the level before (its nerfstudio edges and weights), anneal as set.
                let p = &ch.levels[l - 1];
                let pe = &p.edges[r * (p.n + 1)..(r + 1) * (p.n + 1)];
                let pw = &p.weights[r * p.n..(r + 1) * p.n];
                assert_close(
                    &tw::pdf_resample(pe, pw, n, ch.anneal, 0.5, false),
                    e,
                    EDGES,
                    &format!("level {l} edges"),
                );
            }
            t_edges.extend(e.iter().map(|&s| g.t(s)));
            w.extend(tw::weights(&g, e, &raw[r * n..(r + 1) * n], 0.01));
            if l < 2 {
                let le = &last.edges[r * (last.n + 1)..(r + 1) * (last.n + 1)];
                let lw = &last.weights[r * last.n..(r + 1) * last.n];
                let norm = 1.0 / (ch.rays * last.n) as f64;
                interlevel += tw::interlevel(&g, le, lw, e, &raw[r * n..(r + 1) * n], 0.01, norm).0;
            }
        }
        // The spacing map t = g^-1(s g(far) + (1 - s) g(near)): the f64 forms differ next to s = 1 (1e-13 at t = 1000).
        assert_close(&t_edges, &lv.t_edges, Tol { rel: 1e-11, abs: 0.0, of_max: 0.0 }, &format!("level {l} t edges"));
        assert_close(&w, &lv.weights, WEIGHTS, &format!("level {l} weights"));
    }
    assert_close(&[interlevel], &[ch.interlevel_loss], LOSS, "chain interlevel_loss");
    let zeros = vec![0.0; last.n];
    let raw = inputs(&last.raw);
    let dist: f64 = rows(&last.edges, last.n + 1)
        .zip(rows(&raw, last.n))
        .map(|(e, x)| tw::composite(&distortion_in(g, e, x, &zeros, ch.rays)).loss_dist)
        .sum();
    assert_close(&[dist], &[ch.distortion_loss], LOSS, "chain distortion_loss");
}

// ------------------------------------------------------------------------------------------------ GPU kernels (f32)

fn up(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Activations, data).expect("upload")
}

fn zeros(g: &Context, name: &str, n: usize) -> GpuBuffer<f32> {
    up(g, name, &vec![0.0; n])
}

/// Buffers of `rays` rays along +z from the origin (their positions play no part with contraction on).
struct Rays {
    o: GpuBuffer<f32>,
    d: GpuBuffer<f32>,
    n: usize,
}

impl Rays {
    fn new(g: &Context, n: usize) -> Rays {
        Rays { o: zeros(g, "origins", 3 * n), d: up(g, "dirs", &[0.0, 0.0, 1.0].repeat(n)), n }
    }

    fn buffers(&self) -> RayBuffers<'_> {
        RayBuffers { origins: &self.o, dirs: &self.d, n_rays: self.n, ray_offset: 0 }
    }
}

const EVAL: Jitter = Jitter { seed: 1, step: 0, level: 0, enabled: false };

/// f32 tolerances of the kernels. Edges: the cdf is an f32 running sum of up to 48 terms (error ~ 48 ulp of 1 =
/// 6e-6) and an edge moves by (bin width / bin probability) times that, at most ~3x for these cases: 2e-5
/// absolute. Weights: exp/expm1 in f32, 1e-6 relative plus 1e-7 absolute (accumulated transmittance). Losses: sums
/// of up to 32 positive terms with cancellation in (w - w_outer) and in |m_i - m_j|: 1e-4 relative. Gradients:
/// suffix sums with cancellation, 2e-4 of the array's max.
const EDGES32: Tol = Tol { rel: 0.0, abs: 2e-5, of_max: 0.0 };
const WEIGHTS32: Tol = Tol { rel: 1e-4, abs: 1e-7, of_max: 0.0 };
const LOSS32: Tol = Tol { rel: 2e-5, abs: 1e-12, of_max: 0.0 };
const GRAD32: Tol = Tol { rel: 2e-5, abs: 1e-12, of_max: 2e-5 };
/// The chain's weights at the kernels' own edges (off by up to EDGES32): a weight moves by about
/// sigma (dt/ds) T times the edge error, so 3e-4 relative.
const CHAIN_WEIGHTS32: Tol = Tol { rel: 3e-4, abs: 3e-6, of_max: 0.0 };

#[test]
fn pdf_resample_kernel_matches_nerfstudio_pdf_sampler() {
    let fx: Cases<PdfCase> = load("pdf_sampler.json");
    check_header(&fx.header);
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    for c in &fx.cases {
        let rays = Rays::new(&g, c.rays);
        let (e, w) = (up(&g, "edges", &f32s(&c.edges)), up(&g, "weights", &f32s(&c.weights)));
        let (out, pos) = (zeros(&g, "new edges", c.rays * (c.m + 1)), zeros(&g, "positions", c.rays * c.m * 3));
        let mut rec = g.recorder("pdf").expect("rec");
        k.pdf_resample(
            &mut rec,
            rays.buffers(),
            geometry(&fx.header),
            (c.n, c.m),
            c.anneal as f32,
            EVAL,
            (&e, &w),
            (&out, &pos),
        )
        .expect("pdf_resample");
        rec.submit_and_wait().expect("submit");
        let got = widen(&g.download(&out).expect("download"));
        assert_close(&got, &c.new_edges, EDGES32, &format!("{}: kernel new edges", c.name));
        // Control: u_k moved by 1e-3 of a stratum is outside the f32 tolerance.
        let (e64, w64) = (inputs(&c.edges), inputs(&c.weights));
        let nudged: Vec<f64> = rows(&e64, c.n + 1)
            .zip(rows(&w64, c.n))
            .flat_map(|(e, w)| tw::pdf_resample(e, w, c.m, c.anneal, 0.501, true))
            .collect();
        assert_sensitive(&nudged, &c.new_edges, EDGES32, &c.name);
    }
}

#[test]
fn weights_and_interlevel_kernels_match_nerfstudio_interlevel_loss() {
    let fx: Cases<InterlevelCase> = load("interlevel.json");
    check_header(&fx.header);
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    for c in &fx.cases {
        let (big_n, n) = (c.n_nerf, c.n_prop);
        let rays = Rays::new(&g, c.rays);
        let (ne, nw) = (up(&g, "nerf edges", &f32s(&c.nerf_edges)), up(&g, "nerf weights", &f32s(&c.nerf_weights)));
        let (pe, pr) = (up(&g, "prop edges", &f32s(&c.prop_edges)), up(&g, "prop raw", &f32s(&c.prop_raw)));
        let (pw, dy, losses) = (zeros(&g, "pw", c.rays * n), zeros(&g, "dy", c.rays * n), zeros(&g, "losses", c.rays));
        let pw_out = zeros(&g, "pw copy", c.rays * n);
        let norm = 1.0 / (c.rays * big_n) as f32;
        let geo = geometry(&fx.header);
        let mut rec = g.recorder("interlevel").expect("rec");
        k.weights(&mut rec, rays.buffers(), geo, n, &pe, (&pr, 1), 0.01, &pw_out).expect("weights");
        k.weights(&mut rec, rays.buffers(), geo, n, &pe, (&pr, 1), 0.01, &pw).expect("weights");
        let bufs = InterlevelBuffers {
            nerf_edges: &ne,
            nerf_weights: &nw,
            prop_edges: &pe,
            prop_raw: &pr,
            prop_weights: &pw,
            prop_dy: &dy,
            losses: &losses,
        };
        k.interlevel(&mut rec, rays.buffers(), geo, (big_n, n), 1, 0.01, norm, &bufs).expect("interlevel");
        rec.submit_and_wait().expect("submit");
        let what = |q: &str| format!("{}: kernel {q}", c.name);
        assert_close(&widen(&g.download(&pw_out).expect("pw")), &c.prop_weights, WEIGHTS32, &what("weights"));
        let per_ray: Vec<f64> = g.download(&losses).expect("losses").iter().map(|&l| l as f64 / norm as f64).collect();
        assert_close(&per_ray, &c.per_ray_outer_sum, LOSS32, &what("per-ray loss"));
        let grad = widen(&g.download(&dy).expect("dy"));
        assert_close(&grad, &c.d_loss_d_prop_raw, GRAD32, &what("dL/draw"));
        if c.loss > 1e-6 {
            // Control: NeRF weights 1e-4 larger give per-ray losses outside the f32 tolerance.
            let (ne64, nw64, pe64, pr64) =
                (inputs(&c.nerf_edges), inputs(&c.nerf_weights), inputs(&c.prop_edges), inputs(&c.prop_raw));
            let g64 = geom(&fx.header);
            let nudged: Vec<f64> = (0..c.rays)
                .map(|r| {
                    let nw2: Vec<f64> = nw64[r * big_n..(r + 1) * big_n].iter().map(|&v| v * (1.0 + 1e-4)).collect();
                    let (nei, pei) =
                        (&ne64[r * (big_n + 1)..(r + 1) * (big_n + 1)], &pe64[r * (n + 1)..(r + 1) * (n + 1)]);
                    tw::interlevel(&g64, nei, &nw2, pei, &pr64[r * n..(r + 1) * n], 0.01, 1.0).0
                })
                .collect();
            assert_sensitive(&nudged, &c.per_ray_outer_sum, LOSS32, &c.name);
        }
    }
}

/// Runs the composite kernel with only the distortion loss on: (weights, per-ray loss_dist * rays, dL/draw).
fn distortion_kernel(
    g: &Context,
    k: &RenderKernels,
    h: &Header,
    rays: usize,
    n: usize,
    edges: &[f32],
    raw: &[f32],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let rb = Rays::new(g, rays);
    let (e, d) = (up(g, "edges", edges), up(g, "raw", raw));
    let cols = zeros(g, "colours", rays * n);
    let targets = up(g, "targets", &[0.0, 1.0].repeat(rays)); // band value 0, ray weight 1
    let bw = up(g, "band weights", &[1.0]);
    let (dyd, dyc, w) =
        (zeros(g, "dy density", rays * n), zeros(g, "dy colour", rays * n), zeros(g, "weights", rays * n));
    let out = zeros(g, "ray out", rays * (RAY_OUT_FIXED + 1));
    let p = CompositeParams {
        bands: 1,
        density_stride: 1,
        density_scale: 0.01,
        background: BackgroundMode::Constant(0.0),
        rgb_norm: 0.0,
        dist_norm: 1.0 / rays as f32,
        train: true,
        grad_scaling: false,
        depth: None,
    };
    let bufs = CompositeBuffers {
        edges: &e,
        density: &d,
        colours: &cols,
        targets: &targets,
        band_weights: &bw,
        dy_density: &dyd,
        dy_colour: &dyc,
        weights: &w,
        ray_out: &out,
        depth_targets: None,
    };
    let mut rec = g.recorder("composite").expect("rec");
    k.composite(&mut rec, rb.buffers(), geometry(h), n, &p, &bufs).expect("composite");
    rec.submit_and_wait().expect("submit");
    let out = g.download(&out).expect("ray out");
    let per_ray = rows(&out, RAY_OUT_FIXED + 1).map(|o| o[1] as f64 * rays as f64).collect();
    (widen(&g.download(&w).expect("w")), per_ray, widen(&g.download(&dyd).expect("dy")))
}

#[test]
fn composite_kernel_distortion_matches_nerfstudio_distortion_loss() {
    let fx: Cases<DistortionCase> = load("distortion.json");
    check_header(&fx.header);
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    for c in &fx.cases {
        let (w, per_ray, grad) = distortion_kernel(&g, &k, &fx.header, c.rays, c.n, &f32s(&c.edges), &f32s(&c.raw));
        let what = |q: &str| format!("{}: kernel {q}", c.name);
        assert_close(&w, &c.weights, WEIGHTS32, &what("weights"));
        assert_close(&per_ray, &c.per_ray, LOSS32, &what("per-ray distortion"));
        assert_close(&grad, &c.d_loss_d_raw, GRAD32, &what("dL/draw"));
        if c.per_ray.iter().all(|&l| l > 1e-6) {
            // Control: edges 1e-4 closer to 0 give per-ray losses outside the f32 tolerance.
            let (e64, r64) = (inputs(&c.edges), inputs(&c.raw));
            let zeros = vec![0.0; c.n];
            let nudged: Vec<f64> = rows(&e64, c.n + 1)
                .zip(rows(&r64, c.n))
                .map(|(e, x)| {
                    let e2: Vec<f64> = e.iter().map(|&s| s * (1.0 - 1e-4)).collect();
                    tw::composite(&distortion_in(geom(&fx.header), &e2, x, &zeros, 1)).loss_dist
                })
                .collect();
            assert_sensitive(&nudged, &c.per_ray, LOSS32, &c.name);
        }
    }
}

/// The whole eval-mode sampling chain on the GPU (sample_initial, weights, pdf_resample twice, weights), each level
/// built from the kernels' own level before, as in training, against nerfstudio's ProposalNetworkSampler.
#[test]
fn sampling_chain_kernels_match_nerfstudio_proposal_network_sampler() {
    let ch: Chain = load("proposal_chain.json");
    check_header(&ch.header);
    let g = gpu();
    let k = RenderKernels::new(&g).expect("kernels");
    let rays = Rays::new(&g, ch.rays);
    let geo = geometry(&ch.header);
    let r = ch.rays;
    let lv = &ch.levels;
    let edges: Vec<GpuBuffer<f32>> = lv.iter().map(|l| zeros(&g, "edges", r * (l.n + 1))).collect();
    let pos: Vec<GpuBuffer<f32>> = lv.iter().map(|l| zeros(&g, "positions", r * l.n * 3)).collect();
    let raw: Vec<GpuBuffer<f32>> = lv.iter().map(|l| up(&g, "raw", &f32s(&l.raw))).collect();
    let w: Vec<GpuBuffer<f32>> = lv.iter().map(|l| zeros(&g, "weights", r * l.n)).collect();
    let mut rec = g.recorder("chain").expect("rec");
    k.sample_initial(&mut rec, rays.buffers(), geo, lv[0].n, EVAL, (&edges[0], &pos[0])).expect("sample_initial");
    for l in 0..3 {
        if l > 0 {
            let nm = (lv[l - 1].n, lv[l].n);
            let (src, dst) = ((&edges[l - 1], &w[l - 1]), (&edges[l], &pos[l]));
            k.pdf_resample(&mut rec, rays.buffers(), geo, nm, ch.anneal as f32, EVAL, src, dst).expect("pdf");
        }
        k.weights(&mut rec, rays.buffers(), geo, lv[l].n, &edges[l], (&raw[l], 1), 0.01, &w[l]).expect("weights");
    }
    rec.submit_and_wait().expect("submit");
    for l in 0..3 {
        let got_e = widen(&g.download(&edges[l]).expect("edges"));
        assert_close(&got_e, &lv[l].edges, EDGES32, &format!("level {l} kernel edges"));
        let got_w = widen(&g.download(&w[l]).expect("weights"));
        assert_close(&got_w, &lv[l].weights, CHAIN_WEIGHTS32, &format!("level {l} kernel weights"));
    }
    let last = &lv[2];
    let (_, per_ray, _) =
        distortion_kernel(&g, &k, &ch.header, r, last.n, &f32s_rounded(&last.edges), &f32s(&last.raw));
    let dist = per_ray.iter().sum::<f64>() / r as f64;
    assert_close(&[dist], &[ch.distortion_loss], LOSS32, "chain kernel distortion_loss");
}

/// The chain's f64 intermediate values rounded to f32 (they are no f32 inputs).
fn f32s_rounded(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}
