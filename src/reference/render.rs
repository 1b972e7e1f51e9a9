//! CPU twin of the render kernels (`glsl/render/*.comp`): sampling, PDF resampling, weights, colour-input assembly,
//! compositing with the per-band MSE and distortion losses and their closed-form backward, and the interlevel loss.
//! Generic over f32 (compared with the kernels) and f64 (finite differences). One function per kernel, per ray.

use num_traits::Float;

use crate::maths::c;
pub use crate::maths::field::{contract, hash_input};

pub fn spacing_g<T: Float>(t: T) -> T {
    if t < T::one() {
        c::<T>(0.5) * t
    } else {
        T::one() - c::<T>(0.5) / t
    }
}

pub fn spacing_g_inv<T: Float>(s: T) -> T {
    if s < c(0.5) {
        c::<T>(2.0) * s
    } else {
        T::one() / (c::<T>(2.0) - c::<T>(2.0) * s)
    }
}

/// 1 - g(t) in closed form (no cancellation next to 1).
pub fn spacing_one_minus_g<T: Float>(t: T) -> T {
    if t < T::one() {
        T::one() - c::<T>(0.5) * t
    } else {
        c::<T>(0.5) / t
    }
}

/// Euclidean distance of edge s: g^-1(s g(far) + (1 - s) g(near)), the linear-in-disparity branch evaluated as
/// 0.5 / (s (1 - g(far)) + (1 - s)(1 - g(near))) (the kernels' form: no cancellation next to s = 1, finite for any far).
pub fn edge_to_t<T: Float>(s: T, near: T, far: T) -> T {
    let a = s * spacing_g(far) + (T::one() - s) * spacing_g(near);
    if a < c(0.5) {
        return c::<T>(2.0) * a;
    }
    c::<T>(0.5) / (s * spacing_one_minus_g(far) + (T::one() - s) * spacing_one_minus_g(near))
}

pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// The kernels' per-ray uniform in [0, 1) (exact in f32).
pub fn ray_uniform(seed: u32, step: u32, ray: u32, level: u32) -> f32 {
    let h = pcg_hash(seed ^ pcg_hash(step ^ pcg_hash(ray ^ pcg_hash(level))));
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Geometry of one ray shared by the functions below.
#[derive(Clone, Copy, Debug)]
pub struct RayGeom<T> {
    pub origin: [T; 3],
    pub dir: [T; 3],
    pub near: T,
    pub far: T,
    pub contraction: bool,
}

impl<T: Float> RayGeom<T> {
    pub fn point(&self, t: T) -> [T; 3] {
        [0, 1, 2].map(|k| self.origin[k] + self.dir[k] * t)
    }

    pub fn t(&self, s: T) -> T {
        edge_to_t(s, self.near, self.far)
    }

    /// Hash inputs of the interval midpoints of `edges`.
    pub fn positions(&self, edges: &[T]) -> Vec<[T; 3]> {
        edges
            .windows(2)
            .map(|e| hash_input(self.point(c::<T>(0.5) * (self.t(e[0]) + self.t(e[1]))), self.contraction).0)
            .collect()
    }

    fn inside(&self, tmid: T) -> bool {
        self.contraction || hash_input(self.point(tmid), false).1
    }
}

/// `sample_initial`: n + 1 edges (jittered with `u` when `jitter`).
pub fn initial_edges<T: Float>(n: usize, u: T, jitter: bool) -> Vec<T> {
    let inv = T::one() / c(n as f64);
    (0..=n)
        .map(|k| {
            let e = c::<T>(k as f64) * inv;
            if !jitter {
                return e;
            }
            let lower = if k == 0 { T::zero() } else { e - c::<T>(0.5) * inv };
            let upper = if k == n { T::one() } else { e + c::<T>(0.5) * inv };
            lower + u * (upper - lower)
        })
        .collect()
}

/// The density activation `scale * exp(min(raw, 88))` (the kernels' `density_from_raw`: the cap keeps sigma finite
/// in fp32, so Inf x 0 = NaN cannot happen on a zero-width interval). A NaN raw stays NaN.
pub fn density<T: Float>(raw: T, scale: T) -> T {
    scale * if raw > c(88.0) { c::<T>(88.0) } else { raw }.exp()
}

/// Opacity 1 - exp(-tau) without cancellation (the kernels' `alpha_of`: a 4-term series below 2^-7).
pub fn alpha<T: Float>(tau: T) -> T {
    -(-tau).exp_m1()
}

/// Per-sample (sigma, delta, tmid) of a level.
fn samples<T: Float>(g: &RayGeom<T>, edges: &[T], raw: &[T], scale: T) -> Vec<(T, T, T)> {
    edges
        .windows(2)
        .zip(raw)
        .map(|(e, &r)| {
            let (t0, t1) = (g.t(e[0]), g.t(e[1]));
            let tmid = c::<T>(0.5) * (t0 + t1);
            let sigma = if g.inside(tmid) { density(r, scale) } else { T::zero() };
            (sigma, t1 - t0, tmid)
        })
        .collect()
}

/// The depth inside interval [tmid - delta/2, tmid + delta/2] (constant density sigma, transmittance exp(-excl) at its
/// start, accumulation `a_prev` before it) where the accumulation reaches `level`: solves
/// a_prev + exp(-excl) (1 - exp(-sigma (t - t0))) = level for t, clamped to the interval.
fn level_crossing<T: Float>(level: T, a_prev: T, excl: T, sigma: T, delta: T, tmid: T) -> T {
    let t0 = tmid - c::<T>(0.5) * delta;
    let a = ((level - a_prev) * excl.exp()).max(T::zero());
    if sigma <= T::zero() || a >= T::one() {
        return if a >= T::one() { t0 + delta } else { t0 };
    }
    let t = t0 - (-a).ln_1p() / sigma;
    t.max(t0).min(t0 + delta)
}

fn nan0<T: Float>(v: T) -> T {
    if v.is_nan() {
        T::zero()
    } else {
        v
    }
}

/// `density_weights`.
pub fn weights<T: Float>(g: &RayGeom<T>, edges: &[T], raw: &[T], scale: T) -> Vec<T> {
    let mut acc = T::zero();
    samples(g, edges, raw, scale)
        .into_iter()
        .map(|(sigma, delta, _)| {
            let tau = sigma * delta;
            let w = nan0((-acc).exp() * alpha(tau));
            acc = acc + tau;
            w
        })
        .collect()
}

/// `pdf_resample`: m + 1 new edges.
pub fn pdf_resample<T: Float>(edges: &[T], weights: &[T], m: usize, anneal: T, u: T, jitter: bool) -> Vec<T> {
    let n = weights.len();
    let padded: Vec<T> = weights
        .iter()
        .map(|&w| {
            let w = w.max(T::zero());
            let a = if w == T::zero() && anneal == T::zero() { T::one() } else { w.powf(anneal) };
            a + c(0.01)
        })
        .collect();
    let mut total = padded.iter().fold(T::zero(), |a, &b| a + b);
    let pad = (c::<T>(1e-5) - total).max(T::zero()) / c(n as f64);
    total = total.max(c(1e-5));
    let inv_total = T::one() / total;
    let ju = if jitter { u } else { c(0.5) };
    let inv_m = T::one() / c((m + 1) as f64);
    let mut i = 0;
    let mut cdf_lo = T::zero();
    let mut cdf_hi = T::one().min((padded[0] + pad) * inv_total);
    (0..=m)
        .map(|k| {
            let u = (c::<T>(k as f64) + ju) * inv_m;
            while i < n && cdf_hi <= u {
                i += 1;
                cdf_lo = cdf_hi;
                if i < n {
                    cdf_hi = T::one().min(cdf_hi + (padded[i] + pad) * inv_total);
                }
            }
            if i >= n {
                edges[n]
            } else {
                let den = cdf_hi - cdf_lo;
                let tau = if den > T::zero() { ((u - cdf_lo) / den).max(T::zero()).min(T::one()) } else { T::zero() };
                edges[i] + tau * (edges[i + 1] - edges[i])
            }
        })
        .collect()
}

/// Background of the composite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Background {
    LastSample,
    Constant(f64),
    /// A uniform colour per ray and band from the kernels' random stream (nerfstudio's `random`, training only).
    Random {
        seed: u32,
        step: u32,
        ray: u32,
    },
}

/// Everything `composite` computes for one ray.
#[derive(Clone, Debug)]
pub struct Composite<T> {
    pub weights: Vec<T>,
    pub colour: Vec<T>,
    pub accumulation: T,
    /// Where the accumulation crosses 0.5 (exactly, inside the interval); the last midpoint when it never does.
    pub median_depth: T,
    pub expected_depth: T,
    /// Where the accumulation crosses 0.25 A and 0.75 A (A the ray's total): the spread of the weights; the last
    /// midpoint when A < 1e-4.
    pub depth_q25: T,
    pub depth_q75: T,
    /// band-weighted squared error x rgb_norm x ray weight
    pub loss_rgb: T,
    pub loss_dist: T,
    /// Depth loss x norm x ray weight (0 without a depth target).
    pub loss_depth: T,
    pub d_raw: Vec<T>,
    /// dL/dc, sample-major (n x B)
    pub d_colour: Vec<T>,
}

/// Inputs of `composite` for one ray.
pub struct CompositeIn<'a, T> {
    pub geom: RayGeom<T>,
    pub edges: &'a [T],
    pub raw: &'a [T],
    /// n x B, sample-major
    pub colours: &'a [T],
    pub target: &'a [T],
    pub ray_weight: T,
    pub band_weights: &'a [T],
    pub density_scale: T,
    pub background: Background,
    pub rgb_norm: T,
    pub dist_norm: T,
    /// nerfacto's optional gradient scaling: field-output gradients times clamp(t_mid^2, 0, 1).
    pub grad_scaling: bool,
    /// Depth supervision of this ray (None: off, or no target).
    pub depth: Option<DepthTarget<T>>,
}

/// A ray's depth target and the loss that uses it (docs/geometry.md "Depth supervision").
#[derive(Clone, Copy, Debug)]
pub struct DepthTarget<T> {
    pub loss: crate::nerf::config::DepthLoss,
    /// Target distance along the unit ray and its standard deviation (normalised frame).
    pub distance: T,
    pub sigma: T,
    /// `depth_loss_mult` over the batch's ray weight.
    pub norm: T,
}

/// One sample's depth term (without URF's expected-depth term): (value, dL/dw). DS-NeRF: -log(w + 1e-7) *
/// N(t - d; 0, s) * delta; URF: (w - N(t - d; 0, s/3) delta)^2 inside |t - d| <= s, w^2 in front of d - s
/// (N the normal density: N delta is a probability mass, as w is).
pub fn depth_term<T: Float>(dt: &DepthTarget<T>, w: T, t: T, delta: T) -> (T, T) {
    use crate::nerf::config::DepthLoss;
    let x = t - dt.distance;
    let s = dt.sigma;
    match dt.loss {
        DepthLoss::DsNerf => {
            let k = (-(x * x) / (c::<T>(2.0) * s * s)).exp() / (s * c(std::f64::consts::TAU.sqrt())) * delta;
            let we = w + c(1e-7);
            (-we.ln() * k, -k / we)
        }
        DepthLoss::Urf => {
            let sd = s / c(3.0);
            if x.abs() <= s {
                let nx = (-(c::<T>(0.5)) * x * x / (sd * sd)).exp() / (sd * c(std::f64::consts::TAU.sqrt())) * delta;
                ((w - nx) * (w - nx), c::<T>(2.0) * (w - nx))
            } else if x < -s {
                (w * w, c::<T>(2.0) * w)
            } else {
                (T::zero(), T::zero())
            }
        }
    }
}

pub fn composite<T: Float>(a: &CompositeIn<T>) -> Composite<T> {
    let n = a.raw.len();
    let b_n = a.target.len();
    let s = samples(&a.geom, a.edges, a.raw, a.density_scale);
    let bg: Vec<T> = (0..b_n)
        .map(|b| match a.background {
            Background::LastSample => a.colours[(n - 1) * b_n + b],
            Background::Constant(v) => c(v),
            Background::Random { seed, step, ray } => c(ray_uniform(seed, step, ray, 100 + b as u32) as f64),
        })
        .collect();
    let mut acc = T::zero();
    let mut excl = Vec::with_capacity(n);
    let mut w = Vec::with_capacity(n);
    let (mut big_a, mut big_w, mut big_m, mut dist, mut depth_sum) =
        (T::zero(), T::zero(), T::zero(), T::zero(), T::zero());
    let mut colour = vec![T::zero(); b_n];
    let mut median = None;
    for (i, &(sigma, delta, tmid)) in s.iter().enumerate() {
        let tau = sigma * delta;
        let wi = nan0((-acc).exp() * alpha(tau));
        excl.push(acc);
        acc = acc + tau;
        w.push(wi);
        for (b, cb) in colour.iter_mut().enumerate() {
            *cb = *cb + wi * a.colours[i * b_n + b];
        }
        let (s0, s1) = (a.edges[i], a.edges[i + 1]);
        let m = c::<T>(0.5) * (s0 + s1);
        dist = dist + c::<T>(2.0) * wi * (m * big_w - big_m) + wi * wi * (s1 - s0) / c(3.0);
        big_w = big_w + wi;
        big_m = big_m + wi * m;
        big_a = big_a + wi;
        depth_sum = depth_sum + wi * tmid;
        if median.is_none() && big_a >= c(0.5) {
            median = Some(level_crossing(c(0.5), big_a - wi, excl[i], sigma, delta, tmid));
        }
    }
    let last_mid = s[n - 1].2;
    let median_depth = median.unwrap_or(last_mid);
    let quantile = |q: T| {
        if big_a < c(1e-4) {
            return last_mid; // no surface: the quantiles of rounding-level weights mean nothing
        }
        let level = q * big_a;
        let mut a_prev = T::zero();
        for (i, &(sigma, delta, tmid)) in s.iter().enumerate() {
            if w[i] > T::zero() && a_prev + w[i] >= level {
                return level_crossing(level, a_prev, excl[i], sigma, delta, tmid);
            }
            a_prev = a_prev + w[i];
        }
        last_mid
    };
    let (depth_q25, depth_q75) = (quantile(c(0.25)), quantile(c(0.75)));
    let mut loss = T::zero();
    let mut g_c = vec![T::zero(); b_n];
    for b in 0..b_n {
        colour[b] = colour[b] + bg[b] * (T::one() - big_a);
        // A NaN target: a band the ray did not observe (rig-aware training): no loss, no gradient.
        let e = if a.target[b].is_nan() { T::zero() } else { colour[b] - a.target[b] };
        loss = loss + a.band_weights[b] * e * e;
        g_c[b] = c::<T>(2.0) * a.band_weights[b] * e * a.rgb_norm * a.ray_weight;
    }
    let g_bg = (0..b_n).fold(T::zero(), |acc, b| acc + g_c[b] * bg[b]);
    let expected = depth_sum / (big_a + c(1e-10));
    let depth = a
        .depth
        .filter(|d| d.distance > T::zero() && d.distance.is_finite() && d.sigma > T::zero() && d.sigma.is_finite());
    let loss_depth = depth.map_or(T::zero(), |d| {
        (0..n).fold(T::zero(), |l, i| l + depth_term(&d, w[i], s[i].2, s[i].1).0) * d.norm * a.ray_weight
    });
    let mut d_raw = vec![T::zero(); n];
    let mut d_colour = vec![T::zero(); n * b_n];
    let (mut sfx, mut sw, mut swm) = (T::zero(), T::zero(), T::zero());
    for k in (0..n).rev() {
        let (sigma, delta, tmid) = s[k];
        let gs = if a.grad_scaling { (tmid * tmid).min(T::one()) } else { T::one() };
        let t_next = (-(excl[k] + sigma * delta)).exp();
        let wk = w[k];
        let mut g = -g_bg;
        for b in 0..b_n {
            g = g + g_c[b] * a.colours[k * b_n + b];
            let mut dc = wk * g_c[b];
            if k == n - 1 && a.background == Background::LastSample {
                dc = dc + (T::one() - big_a) * g_c[b];
            }
            d_colour[k * b_n + b] = dc * gs;
        }
        let (s0, s1) = (a.edges[k], a.edges[k + 1]);
        let m = c::<T>(0.5) * (s0 + s1);
        let wk_ = big_w - wk - sw;
        let mk_ = big_m - wk * m - swm;
        let gd = c::<T>(2.0) * (m * wk_ - mk_ + (big_m - mk_ - wk * m) - m * (big_w - wk_ - wk))
            + c::<T>(2.0 / 3.0) * wk * (s1 - s0);
        g = g + gd * a.dist_norm * a.ray_weight;
        if let Some(d) = &depth {
            g = g + depth_term(d, wk, tmid, delta).1 * d.norm * a.ray_weight;
        }
        let dsigma = delta * (g * t_next - sfx);
        let live = a.geom.contraction || sigma > T::zero();
        let grad_scale = a.density_scale * a.raw[k].max(c(-15.0)).min(c(15.0)).exp();
        d_raw[k] = if live { dsigma * grad_scale * gs } else { T::zero() };
        sfx = sfx + g * wk;
        sw = sw + wk;
        swm = swm + wk * m;
    }
    Composite {
        weights: w,
        colour,
        accumulation: big_a,
        median_depth,
        depth_q25,
        depth_q75,
        expected_depth: expected,
        loss_depth,
        loss_rgb: loss * a.rgb_norm * a.ray_weight,
        loss_dist: dist * a.dist_norm * a.ray_weight,
        d_raw,
        d_colour,
    }
}

/// `interlevel` for one ray and proposal level: (loss, dL/draw of the proposal samples).
#[allow(clippy::too_many_arguments)]
pub fn interlevel<T: Float>(
    geom: &RayGeom<T>,
    nerf_edges: &[T],
    nerf_weights: &[T],
    prop_edges: &[T],
    prop_raw: &[T],
    density_scale: T,
    norm: T,
) -> (T, Vec<T>) {
    let n = prop_raw.len();
    let wp = weights(geom, prop_edges, prop_raw, density_scale);
    let mut diff = vec![T::zero(); n];
    let mut loss = T::zero();
    for i in 0..nerf_weights.len() {
        let (c0, c1) = (nerf_edges[i], nerf_edges[i + 1]);
        // lo: last proposal start <= c0 (clamped); hi: first proposal end > c1 (clamped).
        let lo = (0..n).rev().find(|&j| prop_edges[j] <= c0).unwrap_or(0);
        let hi = (0..n).find(|&j| prop_edges[j + 1] > c1).unwrap_or(n - 1);
        let outer = if hi >= lo { (lo..=hi).fold(T::zero(), |a, j| a + wp[j]) } else { T::zero() };
        let wi = nerf_weights[i];
        let excess = (wi - outer).max(T::zero());
        loss = loss + excess * excess / (wi + c(1e-7));
        if excess > T::zero() && hi >= lo {
            let g = c::<T>(-2.0) * excess / (wi + c(1e-7)) * norm;
            for d in diff.iter_mut().take(hi + 1).skip(lo) {
                *d = *d + g;
            }
        }
    }
    (loss * norm, weights_backward(geom, prop_edges, prop_raw, density_scale, &diff))
}

/// dL/draw from dL/dw through the weights of a level (no colour term).
pub fn weights_backward<T: Float>(geom: &RayGeom<T>, edges: &[T], raw: &[T], scale: T, g: &[T]) -> Vec<T> {
    let s = samples(geom, edges, raw, scale);
    let n = raw.len();
    let mut excl = Vec::with_capacity(n);
    let mut acc = T::zero();
    for &(sigma, delta, _) in &s {
        excl.push(acc);
        acc = acc + sigma * delta;
    }
    let mut out = vec![T::zero(); n];
    let mut sfx = T::zero();
    for k in (0..n).rev() {
        let (sigma, delta, _) = s[k];
        let tau = sigma * delta;
        let wk = nan0((-excl[k]).exp() * alpha(tau));
        let dsigma = delta * (g[k] * (-(excl[k] + tau)).exp() - sfx);
        let live = geom.contraction || sigma > T::zero();
        out[k] = if live { dsigma * scale * raw[k].max(c(-15.0)).min(c(15.0)).exp() } else { T::zero() };
        sfx = sfx + g[k] * wk;
    }
    out
}
