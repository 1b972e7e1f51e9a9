//! Shared helpers of the stability suite (tests/stability_*.rs): run the render kernels on hand-made per-ray inputs
//! and compare with the f64 CPU twin (`msnerf::reference::render`), asserting finiteness first.
//!
//! Tolerances (stated once, used by every stability test unless it says otherwise):
//! - forward values (weights, losses, colours, depths): |gpu - ref| <= 1e-5 + 1e-4 |ref|;
//! - gradients (sums with cancellation): |gpu - ref| <= 1e-4 (|ref| + max |ref| of the ray) + 1e-7.
#![allow(dead_code)]

use crate::common;
use msnerf::gpu::{Context, GpuBuffer, MemoryCategory};
use msnerf::nerf::buffers::RAY_OUT_FIXED;
use msnerf::nerf::kernels::{
    CompositeBuffers, CompositeParams, Geometry, InterlevelBuffers, Jitter, RayBuffers, RenderKernels,
};
use msnerf::reference::render as tw;

pub fn up(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Activations, data).expect("upload")
}

pub fn zeros(g: &Context, name: &str, n: usize) -> GpuBuffer<f32> {
    up(g, name, &vec![0.0; n.max(1)])
}

pub fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

pub fn assert_finite(v: &[f32], what: &str) {
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        panic!("{what}[{i}] is {} (not finite)", v[i]);
    }
}

pub fn assert_finite64(v: &[f64], what: &str) {
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        panic!("{what}[{i}] is {} (not finite)", v[i]);
    }
}

/// Forward tolerance: |a - b| <= 1e-5 + 1e-4 |b|.
pub fn check_vals(got: &[f32], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for i in 0..got.len() {
        assert!(common::close(got[i] as f64, want[i], 1e-5, 1e-4), "{what}[{i}]: got {} want {}", got[i], want[i]);
    }
}

/// Gradient tolerance: |a - b| <= 1e-4 (|b| + max|b|) + 1e-7.
pub fn check_grad(got: &[f32], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    let scale = want.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for i in 0..got.len() {
        let (a, b) = (got[i] as f64, want[i]);
        assert!((a - b).abs() <= 1e-4 * (b.abs() + scale) + 1e-7, "{what}[{i}]: got {a} want {b} (scale {scale})");
    }
}

/// A batch of rays in the normalised frame.
#[derive(Clone, Debug)]
pub struct Rays {
    pub o: Vec<[f32; 3]>,
    pub d: Vec<[f32; 3]>,
}

impl Rays {
    /// `n` rays from `origin` along `dir` (normalised here).
    pub fn same(n: usize, origin: [f32; 3], dir: [f32; 3]) -> Rays {
        let l = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        Rays { o: vec![origin; n], d: vec![dir.map(|v| v / l); n] }
    }

    pub fn len(&self) -> usize {
        self.o.len()
    }

    pub fn geom64(&self, i: usize, geo: Geometry) -> tw::RayGeom<f64> {
        tw::RayGeom {
            origin: self.o[i].map(|v| v as f64),
            dir: self.d[i].map(|v| v as f64),
            near: geo.near as f64,
            far: geo.far as f64,
            contraction: geo.contraction,
        }
    }

    pub fn geom32(&self, i: usize, geo: Geometry) -> tw::RayGeom<f32> {
        tw::RayGeom { origin: self.o[i], dir: self.d[i], near: geo.near, far: geo.far, contraction: geo.contraction }
    }
}

/// The render kernels with their context.
pub struct Render<'a> {
    pub g: &'a Context,
    pub k: RenderKernels,
}

/// Inputs of one composite dispatch; every per-ray array is ray-major.
pub struct CompositeCase {
    pub rays: Rays,
    pub n: usize,
    pub bands: usize,
    pub edges: Vec<f32>,
    pub raw: Vec<f32>,
    /// R x n x B
    pub colours: Vec<f32>,
    /// R x (B + 1): B targets and the ray weight
    pub targets: Vec<f32>,
    pub band_w: Vec<f32>,
    pub background: Option<f32>,
    pub geo: Geometry,
    pub scale: f32,
}

impl CompositeCase {
    pub fn nr(&self) -> usize {
        self.rays.len()
    }
    pub fn rgb_norm(&self) -> f32 {
        1.0 / (self.nr() * self.bands) as f32
    }
    pub fn dist_norm(&self) -> f32 {
        0.002 / self.nr() as f32
    }
}

/// Outputs of the composite kernel.
pub struct CompositeOut {
    pub weights: Vec<f32>,
    /// dL/draw per sample
    pub d_raw: Vec<f32>,
    pub d_colour: Vec<f32>,
    /// R x (RAY_OUT_FIXED + B)
    pub ray_out: Vec<f32>,
}

pub struct WeightsOut {
    pub weights: Vec<f32>,
}

impl<'a> Render<'a> {
    pub fn new(g: &'a Context) -> Self {
        Render { g, k: RenderKernels::new(g).expect("render kernels") }
    }

    /// The kernels with the serial per-ray weights and resampling, then with their lanes variants (32 invocations
    /// per ray; `RenderKernels::with_ray_lanes`): the hard cases hold for both.
    pub fn variants(g: &'a Context) -> [Self; 2] {
        [false, true].map(|lanes| Render { g, k: RenderKernels::with_ray_lanes(g, lanes).expect("render kernels") })
    }

    fn ray_bufs(&self, rays: &Rays) -> (GpuBuffer<f32>, GpuBuffer<f32>) {
        (up(self.g, "origins", &rays.o.concat()), up(self.g, "dirs", &rays.d.concat()))
    }

    /// `composite` in training mode (forward, losses and backward) or evaluation mode.
    pub fn composite(&self, c: &CompositeCase, train: bool) -> CompositeOut {
        let g = self.g;
        let (nr, n, bb) = (c.nr(), c.n, c.bands);
        let (o, d) = self.ray_bufs(&c.rays);
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
        let stride = 16;
        let mut density = vec![0.0f32; nr * n * stride];
        for s in 0..nr * n {
            density[s * stride] = c.raw[s];
        }
        let (edges, dens, cols) = (up(g, "edges", &c.edges), up(g, "density", &density), up(g, "colours", &c.colours));
        let (tg, bw) = (up(g, "targets", &c.targets), up(g, "band weights", &c.band_w));
        let dyd = zeros(g, "dy density", nr * n * stride);
        let dyc = zeros(g, "dy colour", nr * n * bb);
        let wts = zeros(g, "weights", nr * n);
        let out = zeros(g, "ray out", nr * (RAY_OUT_FIXED + bb));
        let p = CompositeParams {
            bands: bb,
            density_stride: stride,
            density_scale: c.scale,
            background: c.background.map_or(
                msnerf::nerf::kernels::BackgroundMode::LastSample,
                msnerf::nerf::kernels::BackgroundMode::Constant,
            ),
            rgb_norm: c.rgb_norm(),
            dist_norm: c.dist_norm(),
            grad_scaling: false,
            train,
            depth: None,
        };
        let bufs = CompositeBuffers {
            edges: &edges,
            density: &dens,
            colours: &cols,
            targets: &tg,
            band_weights: &bw,
            dy_density: &dyd,
            dy_colour: &dyc,
            weights: &wts,
            ray_out: &out,
            depth_targets: None,
        };
        let mut rec = g.recorder("composite").expect("rec");
        self.k.composite(&mut rec, rb, c.geo, n, &p, &bufs).expect("composite");
        rec.submit_and_wait().expect("submit");
        let dd = g.download(&dyd).expect("dyd");
        CompositeOut {
            weights: g.download(&wts).expect("w"),
            d_raw: (0..nr * n).map(|s| dd[s * stride]).collect(),
            d_colour: g.download(&dyc).expect("dyc"),
            ray_out: g.download(&out).expect("out"),
        }
    }

    /// `density_weights` of one level.
    pub fn weights(&self, rays: &Rays, geo: Geometry, n: usize, edges: &[f32], raw: &[f32], scale: f32) -> Vec<f32> {
        let g = self.g;
        let (o, d) = self.ray_bufs(rays);
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: rays.len(), ray_offset: 0 };
        let (e, r, w) = (up(g, "edges", edges), up(g, "raw", raw), zeros(g, "weights", rays.len() * n));
        let mut rec = g.recorder("weights").expect("rec");
        self.k.weights(&mut rec, rb, geo, n, &e, (&r, 1), scale, &w).expect("weights");
        rec.submit_and_wait().expect("submit");
        g.download(&w).expect("w")
    }

    /// `sample_initial` (unjittered unless `jitter`): (edges, positions).
    pub fn sample_initial(&self, rays: &Rays, geo: Geometry, n: usize, jitter: bool) -> (Vec<f32>, Vec<f32>) {
        let g = self.g;
        let (o, d) = self.ray_bufs(rays);
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: rays.len(), ray_offset: 0 };
        let (e, p) = (zeros(g, "edges", rays.len() * (n + 1)), zeros(g, "positions", rays.len() * n * 3));
        let mut rec = g.recorder("sample").expect("rec");
        let j = Jitter { seed: 3, step: 1, level: 0, enabled: jitter };
        self.k.sample_initial(&mut rec, rb, geo, n, j, (&e, &p)).expect("sample");
        rec.submit_and_wait().expect("submit");
        (g.download(&e).expect("e"), g.download(&p).expect("p"))
    }

    /// `pdf_resample` from n bins to m samples: (edges, positions). Jitter uses seed 3, step 1, level 1.
    #[allow(clippy::too_many_arguments)]
    pub fn pdf(
        &self,
        rays: &Rays,
        geo: Geometry,
        (n, m): (usize, usize),
        anneal: f32,
        jitter: bool,
        edges: &[f32],
        weights: &[f32],
    ) -> (Vec<f32>, Vec<f32>) {
        let g = self.g;
        let (o, d) = self.ray_bufs(rays);
        let nr = rays.len();
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
        let (ei, wi) = (up(g, "edges in", edges), up(g, "weights", weights));
        let (eo, po) = (zeros(g, "edges out", nr * (m + 1)), zeros(g, "positions", nr * m * 3));
        let mut rec = g.recorder("pdf").expect("rec");
        let j = Jitter { seed: 3, step: 1, level: 1, enabled: jitter };
        self.k.pdf_resample(&mut rec, rb, geo, (n, m), anneal, j, (&ei, &wi), (&eo, &po)).expect("pdf");
        rec.submit_and_wait().expect("submit");
        (g.download(&eo).expect("eo"), g.download(&po).expect("po"))
    }

    /// `interlevel` for one proposal level (weights of the level computed by `density_weights` first):
    /// (loss per ray, dL/draw per proposal sample).
    #[allow(clippy::too_many_arguments)]
    pub fn interlevel(
        &self,
        rays: &Rays,
        geo: Geometry,
        (n_nerf, n_prop): (usize, usize),
        nerf_edges: &[f32],
        nerf_weights: &[f32],
        prop_edges: &[f32],
        prop_raw: &[f32],
        scale: f32,
        norm: f32,
    ) -> (Vec<f32>, Vec<f32>) {
        let g = self.g;
        let nr = rays.len();
        let (o, d) = self.ray_bufs(rays);
        let rb = RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 };
        let (ne, nw) = (up(g, "nerf edges", nerf_edges), up(g, "nerf weights", nerf_weights));
        let (pe, pr) = (up(g, "prop edges", prop_edges), up(g, "prop raw", prop_raw));
        let (pw, dy, losses) =
            (zeros(g, "prop weights", nr * n_prop), zeros(g, "prop dy", nr * n_prop), zeros(g, "losses", nr));
        let mut rec = g.recorder("interlevel").expect("rec");
        self.k.weights(&mut rec, rb, geo, n_prop, &pe, (&pr, 1), scale, &pw).expect("weights");
        let bufs = InterlevelBuffers {
            nerf_edges: &ne,
            nerf_weights: &nw,
            prop_edges: &pe,
            prop_raw: &pr,
            prop_weights: &pw,
            prop_dy: &dy,
            losses: &losses,
        };
        self.k.interlevel(&mut rec, rb, geo, (n_nerf, n_prop), 1, scale, norm, &bufs).expect("interlevel");
        rec.submit_and_wait().expect("submit");
        (g.download(&losses).expect("losses"), g.download(&dy).expect("dy"))
    }
}

/// The f64 twin of `composite` for ray `i` of a case.
pub fn twin_composite(c: &CompositeCase, i: usize) -> tw::Composite<f64> {
    let (n, bb) = (c.n, c.bands);
    let raw = f64s(&c.raw[i * n..(i + 1) * n]);
    let colours = f64s(&c.colours[i * n * bb..(i + 1) * n * bb]);
    let target = f64s(&c.targets[i * (bb + 1)..i * (bb + 1) + bb]);
    let edges = f64s(&c.edges[i * (n + 1)..(i + 1) * (n + 1)]);
    let band_w = f64s(&c.band_w);
    tw::composite(&tw::CompositeIn {
        geom: c.rays.geom64(i, c.geo),
        edges: &edges,
        raw: &raw,
        colours: &colours,
        target: &target,
        ray_weight: c.targets[i * (bb + 1) + bb] as f64,
        band_weights: &band_w,
        density_scale: c.scale as f64,
        background: match c.background {
            None => tw::Background::LastSample,
            Some(v) => tw::Background::Constant(v as f64),
        },
        rgb_norm: c.rgb_norm() as f64,
        dist_norm: c.dist_norm() as f64,
        grad_scaling: false,
        depth: None,
    })
}

/// Runs a composite case on the GPU (training mode), asserts every output and gradient is finite, and compares
/// each ray with the f64 twin (forward and gradient tolerances above). Returns the GPU outputs.
pub fn composite_matches_twin(r: &Render, c: &CompositeCase, what: &str) -> CompositeOut {
    let out = r.composite(c, true);
    assert_finite(&out.weights, &format!("{what}: weights"));
    assert_finite(&out.d_raw, &format!("{what}: dL/draw"));
    assert_finite(&out.d_colour, &format!("{what}: dL/dc"));
    assert_finite(&out.ray_out, &format!("{what}: ray outputs"));
    let (n, bb) = (c.n, c.bands);
    for i in 0..c.nr() {
        let t = twin_composite(c, i);
        assert_finite64(&t.d_raw, &format!("{what}: twin dL/draw"));
        check_vals(&out.weights[i * n..(i + 1) * n], &t.weights, &format!("{what}: ray {i} weights"));
        let ro = &out.ray_out[i * (RAY_OUT_FIXED + bb)..(i + 1) * (RAY_OUT_FIXED + bb)];
        check_vals(
            &ro[..5],
            &[t.loss_rgb, t.loss_dist, t.accumulation, t.median_depth, t.expected_depth],
            &format!("{what}: ray {i} (loss_rgb, loss_dist, accumulation, median, expected depth)"),
        );
        check_vals(&ro[6..8], &[t.depth_q25, t.depth_q75], &format!("{what}: ray {i} depth quantiles q25, q75"));
        check_vals(&ro[RAY_OUT_FIXED..], &t.colour, &format!("{what}: ray {i} colour"));
        check_grad(&out.d_raw[i * n..(i + 1) * n], &t.d_raw, &format!("{what}: ray {i} dL/draw"));
        check_grad(&out.d_colour[i * n * bb..(i + 1) * n * bb], &t.d_colour, &format!("{what}: ray {i} dL/dc"));
    }
    out
}

/// Sorted edges in [0, 1]: `n + 1` values, uniform.
pub fn uniform_edges(n: usize) -> Vec<f32> {
    (0..=n).map(|k| k as f32 / n as f32).collect()
}
