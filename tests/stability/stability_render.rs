//! Stability of the render kernels (weights, PDF resampling, composite with its losses and backward, interlevel)
//! on hard inputs: very dense media, empty space, raw densities whose exp overflows fp32, far planes up to 1e10 and
//! a near plane of 0, saturated reflectances and targets outside (0, 1). Every case runs on the GPU and is compared
//! with the f64 CPU twin (`msnerf::reference::render`) after asserting that every output and gradient is finite.
//! Tolerances (tests/stability_support): forward |a-b| <= 1e-5 + 1e-4|b|; gradients |a-b| <= 1e-4 (|b| + max|b|) +
//! 1e-7 per ray. Each case says what breaks without its guard; docs/stability.md lists the guards.

use crate::common;
use crate::stability_support;
use common::gpu;
use msnerf::nerf::buffers::{RayOut, RAY_OUT_FIXED};
use msnerf::nerf::kernels::Geometry;
use msnerf::reference::render as tw;
use stability_support::*;

const CONTRACTED: Geometry = Geometry { near: 0.05, far: 1000.0, contraction: true };

/// Raw densities giving sigma * delta = tau[i] for the intervals of `edges` (f64 geometry, density scale 0.01).
fn raw_for_tau(edges: &[f32], geo: Geometry, tau: &[f64]) -> Vec<f32> {
    edges
        .windows(2)
        .zip(tau)
        .map(|(e, &tau)| {
            let t0 = tw::edge_to_t(e[0] as f64, geo.near as f64, geo.far as f64);
            let t1 = tw::edge_to_t(e[1] as f64, geo.near as f64, geo.far as f64);
            if tau == 0.0 {
                -200.0 // exp(-200) underflows to exactly 0 in fp32
            } else {
                (tau / (0.01 * (t1 - t0))).ln() as f32
            }
        })
        .collect()
}

fn colours(nr: usize, n: usize, bands: usize) -> Vec<f32> {
    (0..nr * n * bands).map(|i| 0.05 + 0.9 * ((i * 37 % 101) as f32 / 100.0)).collect()
}

fn targets(nr: usize, bands: usize, vals: &[f32]) -> Vec<f32> {
    let mut t = Vec::new();
    for i in 0..nr {
        t.extend((0..bands).map(|b| vals[(i + b) % vals.len()]));
        t.push(1.0);
    }
    t
}

fn case(rays: Rays, n: usize, bands: usize, edges: Vec<f32>, raw: Vec<f32>, geo: Geometry) -> CompositeCase {
    let nr = rays.len();
    CompositeCase {
        rays,
        n,
        bands,
        edges,
        raw,
        colours: colours(nr, n, bands),
        targets: targets(nr, bands, &[0.2, 0.7, 0.45]),
        band_w: (0..bands).map(|b| 0.5 + 0.25 * b as f32).collect(),
        background: None,
        geo,
        scale: 0.01,
    }
}

/// Checks the weights kernel against the twin and the rendering invariants for every ray.
fn weights_match_twin(r: &Render, rays: &Rays, geo: Geometry, n: usize, edges: &[f32], raw: &[f32], what: &str) {
    let w = r.weights(rays, geo, n, edges, raw, 0.01);
    assert_finite(&w, what);
    for i in 0..rays.len() {
        let e = f64s(&edges[i * (n + 1)..(i + 1) * (n + 1)]);
        let want = tw::weights(&rays.geom64(i, geo), &e, &f64s(&raw[i * n..(i + 1) * n]), 0.01);
        check_vals(&w[i * n..(i + 1) * n], &want, &format!("{what}: ray {i} weights"));
        let sum: f32 = w[i * n..(i + 1) * n].iter().sum();
        assert!(w[i * n..(i + 1) * n].iter().all(|&v| (0.0..=1.0).contains(&v)) && sum <= 1.0 + 1e-5, "{what}");
    }
}

/// PDF resampling of `weights` on the GPU against the twin; edges sorted, inside [0, 1], positions finite.
fn pdf_matches_twin(r: &Render, rays: &Rays, geo: Geometry, nm: (usize, usize), edges: &[f32], w: &[f32]) -> Vec<f32> {
    let (n, m) = nm;
    for (anneal, jitter) in [(1.0f32, false), (0.3, true), (0.0, true)] {
        let (e, p) = r.pdf(rays, geo, (n, m), anneal, jitter, edges, w);
        assert_finite(&e, "resampled edges");
        assert_finite(&p, "resampled positions");
        for i in 0..rays.len() {
            let u = tw::ray_uniform(3, 1, i as u32, 1) as f64;
            let want = tw::pdf_resample(
                &f64s(&edges[i * (n + 1)..(i + 1) * (n + 1)]),
                &f64s(&w[i * n..(i + 1) * n]),
                m,
                anneal as f64,
                u,
                jitter,
            );
            let got = &e[i * (m + 1)..(i + 1) * (m + 1)];
            check_vals(got, &want, &format!("ray {i} resampled edges (anneal {anneal})"));
            assert!(got.windows(2).all(|x| x[0] <= x[1]), "ray {i}: resampled edges sorted: {got:?}");
            assert!(got.iter().all(|&x| (0.0..=1.0).contains(&x)), "ray {i}: resampled edges in [0, 1]");
        }
        assert!(p.iter().all(|&x| (0.0..=1.0).contains(&x)), "hash inputs inside the unit cube");
        if anneal == 1.0 && !jitter {
            return e;
        }
    }
    unreachable!()
}

/// Interlevel loss and gradient on the GPU against the twin.
#[allow(clippy::too_many_arguments)]
fn interlevel_matches_twin(
    r: &Render,
    rays: &Rays,
    geo: Geometry,
    (n_nerf, n_prop): (usize, usize),
    ne: &[f32],
    nw: &[f32],
    pe: &[f32],
    praw: &[f32],
    what: &str,
) -> f64 {
    let norm = 1.0 / (rays.len() * n_nerf) as f32;
    let (loss, dy) = r.interlevel(rays, geo, (n_nerf, n_prop), ne, nw, pe, praw, 0.01, norm);
    assert_finite(&loss, &format!("{what}: interlevel loss"));
    assert_finite(&dy, &format!("{what}: interlevel dL/draw"));
    let mut total = 0.0;
    for i in 0..rays.len() {
        let (l, g) = tw::interlevel(
            &rays.geom64(i, geo),
            &f64s(&ne[i * (n_nerf + 1)..(i + 1) * (n_nerf + 1)]),
            &f64s(&nw[i * n_nerf..(i + 1) * n_nerf]),
            &f64s(&pe[i * (n_prop + 1)..(i + 1) * (n_prop + 1)]),
            &f64s(&praw[i * n_prop..(i + 1) * n_prop]),
            0.01,
            norm as f64,
        );
        assert_finite64(&g, "twin interlevel gradient");
        assert!(common::close(loss[i] as f64, l, 1e-7, 1e-4), "{what}: ray {i} interlevel loss {} vs {l}", loss[i]);
        check_grad(&dy[i * n_prop..(i + 1) * n_prop], &g, &format!("{what}: ray {i} interlevel dL/draw"));
        total += l;
    }
    total
}

/// Very dense media: sigma x delta from 1e-2 up to 1e4 per interval. Transmittance exp(-sum) underflows to exactly
/// 0 behind the first opaque interval. Guard: transmittance is exp(-exclusive prefix) (no cumprod of 1 - alpha,
/// no division by T), so underflow gives clean zeros instead of 0/0; the backward uses T_{k+1} = exp(-(prefix +
/// tau_k)) and suffix sums, never w / T.
#[test]
fn dense_media_weights_resampling_composite_and_interlevel_stay_finite() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (nr, n, bands) = (5, 24, 4);
        let rays = Rays::same(nr, [0.1, -0.2, 0.3], [0.3, 0.5, -0.8]);
        let geo = CONTRACTED;
        let edges: Vec<f32> = (0..nr).flat_map(|_| uniform_edges(n)).collect();
        let profiles: Vec<Vec<f64>> = vec![
            vec![1e4; n],                                                                 // opaque from the first sample
            (0..n).map(|i| 10f64.powf(-2.0 + 6.0 * i as f64 / (n - 1) as f64)).collect(), // 1e-2 .. 1e4
            (0..n).map(|i| if i % 2 == 0 { 0.0 } else { 1e4 }).collect(),                 // empty / opaque alternating
            (0..n).map(|i| if i == n / 2 { 1e4 } else { 0.0 }).collect(),                 // one opaque wall mid-ray
            (0..n).map(|i| if i >= n - 3 { 1e4 } else { 1e3 }).collect(),                 // dense everywhere
        ];
        let raw: Vec<f32> =
            profiles.iter().enumerate().flat_map(|(i, p)| raw_for_tau(&edges[i * (n + 1)..], geo, p)).collect();
        weights_match_twin(&r, &rays, geo, n, &edges, &raw, "dense weights");
        for bg in [None, Some(1.0)] {
            let mut c = case(rays.clone(), n, bands, edges.clone(), raw.clone(), geo);
            c.background = bg;
            let out = composite_matches_twin(&r, &c, "dense composite");
            for i in 0..nr {
                let a = out.ray_out[i * (RAY_OUT_FIXED + bands) + RayOut::Accumulation.col()];
                assert!((a - 1.0).abs() < 1e-5, "ray {i}: opaque ray accumulates 1, got {a}");
            }
        }
        // Resample the dense weights (a one-hot pdf), then the interlevel loss of a dense proposal level.
        let w = r.weights(&rays, geo, n, &edges, &raw, 0.01);
        let m = 12;
        let ne = pdf_matches_twin(&r, &rays, geo, (n, m), &edges, &w);
        let nw: Vec<f32> = (0..nr * m).map(|i| if i % m == m / 2 { 1.0 } else { 0.0 }).collect();
        let loss = interlevel_matches_twin(&r, &rays, geo, (m, n), &ne, &nw, &edges, &raw, "dense interlevel");
        assert!(loss > 0.0, "the case exercises the interlevel loss");
    }
}

/// Empty space: every density underflows to 0, so every weight is 0 and the accumulation is 0. Guards: the PDF adds
/// 0.01 per bin and floors the sum at 1e-5 (no 0/0 cdf, uniform resampling), the inverse cdf treats a zero-width
/// bin as tau = 0, interlevel divides by w + 1e-7, expected depth by A + 1e-10, the median depth falls back to the
/// last sample; the colour is the background alone.
#[test]
fn empty_space_gives_zero_weights_and_finite_everything() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (nr, n, bands) = (3, 16, 3);
        let rays = Rays::same(nr, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        let edges: Vec<f32> = (0..nr).flat_map(|_| uniform_edges(n)).collect();
        for (geo, raw_v) in
            [(CONTRACTED, -200.0f32), (CONTRACTED, -40.0), (Geometry { contraction: false, ..CONTRACTED }, 5.0)]
        {
            // Without contraction the rays leave the [-1, 1]^3 box after t = 1: density is masked to 0 there.
            let raw = vec![raw_v; nr * n];
            weights_match_twin(&r, &rays, geo, n, &edges, &raw, "empty weights");
            for bg in [None, Some(0.0), Some(1.0)] {
                let mut c = case(rays.clone(), n, bands, edges.clone(), raw.clone(), geo);
                c.background = bg;
                let out = composite_matches_twin(&r, &c, "empty composite");
                if raw_v == -200.0 {
                    assert!(out.weights.iter().all(|&w| w == 0.0), "all weights zero");
                    for i in 0..nr {
                        let ro = &out.ray_out[i * (RAY_OUT_FIXED + bands)..(i + 1) * (RAY_OUT_FIXED + bands)];
                        assert_eq!(RayOut::Accumulation.of(ro), 0.0, "accumulation");
                        assert_eq!(RayOut::ExpectedDepth.of(ro), 0.0, "expected depth of an empty ray");
                        assert_eq!(RayOut::LossDistortion.of(ro), 0.0, "distortion of an empty ray");
                    }
                }
            }
            let w = r.weights(&rays, geo, n, &edges, &raw, 0.01);
            let m = 8;
            let ne = pdf_matches_twin(&r, &rays, geo, (n, m), &edges, &w);
            let nw = vec![0.0f32; nr * m];
            let loss = interlevel_matches_twin(&r, &rays, geo, (m, n), &ne, &nw, &edges, &raw, "empty interlevel");
            assert_eq!(loss, 0.0);
        }
    }
}

/// Raw densities above 88 make exp overflow fp32 (sigma = +Inf). With an interval of zero width (duplicate edges,
/// which PDF resampling produces when u runs past the last cdf value) sigma x delta = Inf x 0 = NaN, which turned
/// every later weight into NaN (zeroed by nan_to_num) and the backward's T_{k+1} = exp(-NaN) into NaN gradients.
/// Guard: the density activation evaluates exp(min(raw, 88)) (finite, 1.65e38; 88 is the largest integer whose exp
/// is a finite float), the same in the twin; the backward keeps trunc_exp's derivative exp(clamp(raw, -15, 15)).
#[test]
fn raw_density_above_88_gives_finite_weights_and_gradients() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (nr, n, bands) = (4, 12, 3);
        let rays = Rays::same(nr, [0.2, 0.1, -0.1], [-0.4, 0.2, 0.9]);
        let geo = CONTRACTED;
        let mut edges = Vec::new();
        for i in 0..nr {
            let mut e = uniform_edges(n);
            if i % 2 == 1 {
                // zero-width intervals 3 and 4 (edges 3..=5 equal)
                e[4] = e[3];
                e[5] = e[3];
            }
            edges.extend(e);
        }
        let big = [89.0f32, 100.0, 1e4, f32::MAX];
        let raw: Vec<f32> = (0..nr * n)
            .map(|s| {
                let (i, k) = (s / n, s % n);
                if (3..=4).contains(&k) {
                    big[i]
                } else if k == 7 {
                    big[(i + 1) % 4]
                } else {
                    -1.0
                }
            })
            .collect();
        weights_match_twin(&r, &rays, geo, n, &edges, &raw, "overflow weights");
        for bg in [None, Some(0.5)] {
            let mut c = case(rays.clone(), n, bands, edges.clone(), raw.clone(), geo);
            c.background = bg;
            composite_matches_twin(&r, &c, "overflow composite");
        }
        let w = r.weights(&rays, geo, n, &edges, &raw, 0.01);
        let m = 6;
        let ne = pdf_matches_twin(&r, &rays, geo, (n, m), &edges, &w);
        let nw: Vec<f32> = (0..nr * m).map(|i| if i % m == 1 { 0.9 } else { 0.02 }).collect();
        interlevel_matches_twin(&r, &rays, geo, (m, n), &ne, &nw, &edges, &raw, "overflow interlevel");
        // The trunc_exp derivative stays the clamped exp(15) x 0.01 however large the raw value.
        let c = case(rays.clone(), n, bands, edges.clone(), raw.clone(), geo);
        let out = r.composite(&c, true);
        let bound = 0.01 * 15f32.exp() * 1e3; // delta < 1e3, |g|, |S| <= a few units
        assert!(out.d_raw.iter().all(|v| v.abs() < bound), "bounded trunc_exp gradients");
    }
}

/// Far plane 1e6 (and 1e10) with near plane 0: the spacing inverse 1/(2 - 2s) cancels catastrophically in fp32 next
/// to s = 1 (5 % error in the last edge's t at far = 1e6) and becomes 1/0 = Inf once g(far) rounds to 1 (far above
/// ~1.7e7): Inf sample positions, NaN contraction (Inf/Inf), NaN hash inputs. Guard: edge_to_t evaluates the s >= 0.5
/// branch as 0.5 / (s (1 - g(far)) + (1 - s)(1 - g(near))) with 1 - g(t) = 0.5/t in closed form: no cancellation,
/// t(1) = far. Near = 0 puts the first sample at the ray origin (g(0) = 0).
#[test]
fn far_plane_1e6_and_near_plane_0_match_the_f64_twin() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (nr, n, bands) = (3, 32, 3);
        let rays = Rays {
            o: vec![[0.0, 0.0, 0.0], [0.9, -0.9, 0.5], [1.0, 1.0, 1.0]],
            d: vec![[0.0, 0.0, -1.0], [0.6, 0.0, 0.8], [0.0, 1.0, 0.0]],
        };
        for far in [1e6f32, 1e10] {
            for contraction in [true, false] {
                let geo = Geometry { near: 0.0, far, contraction };
                let (edges, pos) = r.sample_initial(&rays, geo, n, false);
                assert_finite(&pos, "positions");
                for i in 0..nr {
                    let gm = rays.geom64(i, geo);
                    let e = f64s(&edges[i * (n + 1)..(i + 1) * (n + 1)]);
                    assert_eq!(e[0], 0.0);
                    assert_eq!(e[n], 1.0);
                    assert!((gm.t(e[0])).abs() < 1e-12, "near = 0: first edge at the origin");
                    assert!((gm.t(e[n]) - far as f64).abs() <= 1e-6 * far as f64, "last edge at the far plane");
                    let want: Vec<f64> = gm.positions(&e).concat();
                    check_vals(&pos[i * n * 3..(i + 1) * n * 3], &want, &format!("far {far} ray {i} positions"));
                }
                let raw: Vec<f32> = (0..nr * n).map(|s| -3.0 + (s % 7) as f32).collect();
                weights_match_twin(&r, &rays, geo, n, &edges, &raw, "far-plane weights");
                let c = case(rays.clone(), n, bands, edges.clone(), raw.clone(), geo);
                composite_matches_twin(&r, &c, &format!("far {far} composite"));
                let w = r.weights(&rays, geo, n, &edges, &raw, 0.01);
                pdf_matches_twin(&r, &rays, geo, (n, 16), &edges, &w);
            }
        }
        // The twin itself: t(s) is continuous and increasing up to far for every far, in f32 as in f64.
        for far in [1e3f32, 1e6, 1e10, 1e30] {
            let ts: Vec<f32> = (0..=1000).map(|k| tw::edge_to_t(k as f32 / 1000.0, 0.0, far)).collect();
            assert!(ts.iter().all(|t| t.is_finite()), "far {far}: finite");
            assert!(ts.windows(2).all(|w| w[0] <= w[1]), "far {far}: non-decreasing");
            assert!((ts[1000] - far).abs() <= 1e-6 * far, "far {far}: t(1) = {} ", ts[1000]);
        }
    }
}

/// Reflectance exactly 0 and 1 (a saturated sigmoid) and targets outside (0, 1) (black-level overshoot, HDR): the
/// composite's MSE and its backward are polynomial in these values, so they stay finite; the evaluation output is
/// clamped to [0, 1] (nan_to_num first) as nerfstudio does.
#[test]
fn saturated_reflectance_and_targets_outside_the_unit_interval() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (nr, n, bands) = (6, 10, 4);
        let rays = Rays::same(nr, [0.0, 0.3, 0.0], [1.0, 0.0, 0.2]);
        let geo = CONTRACTED;
        let edges: Vec<f32> = (0..nr).flat_map(|_| uniform_edges(n)).collect();
        let raw: Vec<f32> = (0..nr * n).map(|s| (s % 5) as f32 - 1.0).collect();
        let mut c = case(rays.clone(), n, bands, edges, raw, geo);
        c.colours = (0..nr * n * bands).map(|i| if (i / 3) % 2 == 0 { 0.0 } else { 1.0 }).collect();
        c.targets = targets(nr, bands, &[0.0, 1.0, -0.25, 1.25, 0.0, 1.0, 2.0]);
        for bg in [None, Some(0.0), Some(1.0)] {
            c.background = bg;
            composite_matches_twin(&r, &c, "saturated composite");
            let eval = r.composite(&c, false);
            for i in 0..nr {
                let col = &eval.ray_out[i * (RAY_OUT_FIXED + bands) + RAY_OUT_FIXED..(i + 1) * (RAY_OUT_FIXED + bands)];
                assert!(col.iter().all(|v| (0.0..=1.0).contains(v)), "evaluation colours clamped: {col:?}");
            }
        }
    }
}

/// The median and the depth quantiles are exact crossings, not interval midpoints: a slab of constant density sigma
/// from t_a to t_b (empty before and after) accumulates A(t) = 1 - exp(-sigma (t - t_a)), so the median lies at
/// t_a + ln 2 / sigma and the crossing of q A_total at t_a - ln(1 - q A_total) / sigma (closed form, plain f64, not
/// the twin). The slab is cut into 10 intervals, so a midpoint estimate would miss by up to half of one.
#[test]
fn median_and_quantiles_are_exact_crossings() {
    let g = gpu();
    for r in Render::variants(&g) {
        let (n, bands) = (24usize, 3usize);
        let geo = Geometry { near: 0.05, far: 1000.0, contraction: false };
        // A ray along +x from the origin stays inside the [-1, 1]^3 box up to t = 1: the slab is [0.3, 0.8].
        let rays = Rays::same(3, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        // s in [0, 0.45] maps to t < 1 (the linear branch of the spacing: t = 2 (s g(far) + (1 - s) g(near))).
        let edges_one: Vec<f32> = (0..=n).map(|i| i as f32 / n as f32 * 0.45).collect();
        let ts: Vec<f64> = edges_one.iter().map(|&s| tw::edge_to_t(s as f64, 0.05, 1000.0)).collect();
        let (ia, ib) = (ts.iter().position(|&t| t >= 0.3).unwrap(), ts.iter().position(|&t| t >= 0.8).unwrap());
        let (t_a, t_b) = (ts[ia], ts[ib]);
        assert!(ib - ia >= 8, "the slab spans several intervals ({} .. {})", ia, ib);
        for sigma in [2.0f64, 8.0, 40.0] {
            let tau: Vec<f64> =
                (0..n).map(|i| if i >= ia && i < ib { sigma * (ts[i + 1] - ts[i]) } else { 0.0 }).collect();
            let raw = raw_for_tau(&edges_one, geo, &tau);
            let c = case(rays.clone(), n, bands, edges_one.repeat(3), raw.repeat(3), geo);
            let out = composite_matches_twin(&r, &c, "slab composite");
            let ro = &out.ray_out[..RAY_OUT_FIXED + bands];
            let total = 1.0 - (-sigma * (t_b - t_a)).exp();
            let cross = |level: f64| t_a - (1.0 - level).ln() / sigma;
            let cell = (t_b - t_a) / (ib - ia) as f64;
            let tol = 2e-4 + 1e-3 * cell;
            let (acc, median) = (RayOut::Accumulation.of(ro) as f64, RayOut::MedianDepth.of(ro) as f64);
            assert!((acc - total).abs() < 1e-4, "sigma {sigma}: accumulation {acc} want {total}");
            if total >= 0.5 {
                let want = t_a + 2f64.ln() / sigma;
                assert!((median - want).abs() < tol, "sigma {sigma}: median {median} want {want}");
            }
            let (q25, q75) = (cross(0.25 * total), cross(0.75 * total));
            let (g25, g75) = (RayOut::DepthQ25.of(ro) as f64, RayOut::DepthQ75.of(ro) as f64);
            assert!((g25 - q25).abs() < tol, "sigma {sigma}: q25 {g25} want {q25}");
            assert!((g75 - q75).abs() < tol, "sigma {sigma}: q75 {g75} want {q75}");
        }
    }
}
