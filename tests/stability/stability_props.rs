//! Property tests of the rendering invariants (proptest, bounded case counts): on the CPU twin in f32 (the kernels'
//! arithmetic) and f64 over random rays, edges, raw densities from -200 to 1e4 (empty to overflowing), far planes up
//! to 1e10; a few on the GPU. Invariants, with fp32 rounding allowances:
//! - every weight in [0, 1] (>= -1e-7), their sum <= 1 + 1e-5;
//! - transmittance T_i = exp(-prefix) non-increasing; accumulation + final transmittance = 1 (|.| <= 1e-5);
//! - PDF-resampled edges sorted and inside [0, 1] (so are the initial edges), positions inside [0, 1]^3;
//! - composite and interlevel gradients finite.

use crate::common;
use crate::stability_support;
use common::gpu;
use msnerf::nerf::buffers::{RayOut, RAY_OUT_FIXED};
use msnerf::nerf::kernels::Geometry;
use msnerf::reference::render as tw;
use proptest::prelude::*;
use stability_support::*;

/// A ray geometry in the normalised frame.
fn geom() -> impl Strategy<Value = tw::RayGeom<f32>> {
    (
        prop::array::uniform3(-1.5f32..1.5),
        prop::array::uniform3(-1.0f32..1.0),
        prop_oneof![Just(0.0f32), 0.0f32..0.1],
        prop_oneof![Just(1000.0f32), Just(1e6f32), Just(1e10f32), 2.0f32..100.0],
        any::<bool>(),
    )
        .prop_map(|(origin, d, near, far, contraction)| {
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
            tw::RayGeom {
                origin,
                dir: [d[0] / l, d[1] / l, d[2] / l + if l <= 1e-3 { 1.0 } else { 0.0 }],
                near,
                far,
                contraction,
            }
        })
}

/// Sorted edges in [0, 1] (duplicates allowed: zero-width intervals happen after PDF resampling).
fn edges(n: usize) -> impl Strategy<Value = Vec<f32>> {
    prop::collection::vec(prop_oneof![4 => 0.0f32..=1.0, 1 => Just(0.5f32), 1 => Just(1.0f32)], n + 1).prop_map(
        |mut e| {
            e.sort_by(f32::total_cmp);
            e[0] = 0.0f32.min(e[0]);
            e
        },
    )
}

/// Raw densities from empty (-200) to overflowing exp (1e4).
fn raws(n: usize) -> impl Strategy<Value = Vec<f32>> {
    prop::collection::vec(prop_oneof![3 => -8.0f32..12.0, 1 => Just(-200.0f32), 1 => 80.0f32..1e4], n)
}

fn transmittance<T: num_traits::Float>(g: &tw::RayGeom<T>, edges: &[T], raw: &[T]) -> Vec<T> {
    let mut acc = T::zero();
    let mut out = vec![T::one()];
    for (e, &r) in edges.windows(2).zip(raw) {
        let (t0, t1) = (g.t(e[0]), g.t(e[1]));
        let mid = (t0 + t1) / T::from(2.0).unwrap();
        let inside = g.contraction || tw::hash_input(g.point(mid), false).1;
        let sigma = if inside { tw::density(r, T::from(0.01).unwrap()) } else { T::zero() };
        acc = acc + sigma * (t1 - t0);
        out.push((-acc).exp());
    }
    out
}

fn to64(g: &tw::RayGeom<f32>) -> tw::RayGeom<f64> {
    tw::RayGeom {
        origin: g.origin.map(|v| v as f64),
        dir: g.dir.map(|v| v as f64),
        near: g.near as f64,
        far: g.far as f64,
        contraction: g.contraction,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// Weights in [0, 1] summing to at most 1, T non-increasing, A + T_final = 1, in f32 and f64.
    #[test]
    fn weights_transmittance_and_accumulation(g in geom(), (e, raw) in (4usize..40).prop_flat_map(|n| (edges(n), raws(n)))) {
        let w = tw::weights(&g, &e, &raw, 0.01f32);
        prop_assert!(w.iter().all(|&x| x.is_finite() && (-1e-7..=1.0).contains(&x)), "{w:?}");
        let a: f32 = w.iter().sum();
        prop_assert!(a <= 1.0 + 1e-5, "sum {a}");
        let t = transmittance(&g, &e, &raw);
        prop_assert!(t.windows(2).all(|p| p[1] <= p[0]), "T non-increasing: {t:?}");
        prop_assert!((a + t[t.len() - 1] - 1.0).abs() <= 1e-5, "A {a} + T {} = 1", t[t.len() - 1]);
        let g64 = to64(&g);
        let (e64, r64) = (f64s(&e), f64s(&raw));
        let w64 = tw::weights(&g64, &e64, &r64, 0.01);
        let a64: f64 = w64.iter().sum();
        let t64 = transmittance(&g64, &e64, &r64);
        prop_assert!(w64.iter().all(|&x| (0.0..=1.0).contains(&x)) && a64 <= 1.0 + 1e-12);
        prop_assert!((a64 + t64[t64.len() - 1] - 1.0).abs() <= 1e-12);
    }

    /// PDF resampling: sorted edges inside [0, 1], for any weights (zero, one-hot, huge) and anneal in [0, 1].
    #[test]
    fn pdf_resampled_edges_sorted_in_unit_interval(
        (e, w) in (2usize..40).prop_flat_map(|n| (edges(n), prop::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..1.0, Just(1.0f32)], n))),
        m in 1usize..64, anneal in prop_oneof![Just(0.0f32), 0.0f32..=1.0, Just(1.0f32)], u in 0.0f32..1.0, jitter: bool,
    ) {
        let out = tw::pdf_resample(&e, &w, m, anneal, u, jitter);
        prop_assert_eq!(out.len(), m + 1);
        prop_assert!(out.iter().all(|&x| (0.0..=1.0).contains(&x)), "{out:?}");
        prop_assert!(out.windows(2).all(|p| p[0] <= p[1]), "sorted: {out:?}");
        let init = tw::initial_edges(m, u, jitter);
        prop_assert!(init.windows(2).all(|p| p[0] <= p[1]) && init.iter().all(|&x| (0.0..=1.0).contains(&x)));
    }

    /// Composite and interlevel gradients (f64 twin) are finite for any geometry, density and colour.
    #[test]
    fn composite_and_interlevel_gradients_finite(
        g in geom(),
        (e, raw, cols) in (2usize..24).prop_flat_map(|n| (edges(n), raws(n), prop::collection::vec(0.0f32..=1.0, 2 * n))),
        target in prop::array::uniform2(-0.5f32..1.5), bg in prop_oneof![Just(None), Just(Some(0.0)), Just(Some(1.0))],
    ) {
        let g64 = to64(&g);
        let (e64, r64, c64) = (f64s(&e), f64s(&raw), f64s(&cols));
        let t = tw::composite(&tw::CompositeIn {
            geom: g64,
            edges: &e64,
            raw: &r64,
            colours: &c64,
            target: &f64s(&target),
            ray_weight: 1.0,
            band_weights: &[1.0, 0.5],
            density_scale: 0.01,
            background: bg.map_or(tw::Background::LastSample, tw::Background::Constant),
            rgb_norm: 0.5,
            dist_norm: 0.002,
            grad_scaling: false,
            depth: None,
        });
        prop_assert!(t.d_raw.iter().chain(&t.d_colour).all(|v| v.is_finite()), "{:?} {:?}", t.d_raw, t.d_colour);
        prop_assert!(t.loss_rgb.is_finite() && t.loss_dist.is_finite() && t.expected_depth.is_finite());
        let ne = tw::initial_edges(8, 0.5, false);
        let (loss, grad) = tw::interlevel(&g64, &ne, &t.weights[..t.weights.len().min(8)].iter().copied().chain(std::iter::repeat(0.0)).take(8).collect::<Vec<_>>(), &e64, &r64, 0.01, 0.1);
        prop_assert!(loss.is_finite() && grad.iter().all(|v| v.is_finite()), "{loss} {grad:?}");
    }
}

/// The same invariants on the GPU kernels for a few random batches (one context; 8 batches of 16 rays).
#[test]
fn gpu_weights_resampling_and_composite_keep_the_invariants() {
    let g = gpu();
    let r = Render::new(&g);
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases: 8,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let n = 16;
    let strat = (prop::collection::vec(geom(), 16), prop::collection::vec((edges(n), raws(n)), 16));
    runner
        .run(&strat, |(geoms, cases)| {
            // The kernels take one geometry per dispatch: use the first ray's planes and contraction for all.
            let geo = Geometry { near: geoms[0].near, far: geoms[0].far, contraction: geoms[0].contraction };
            let rays = Rays { o: geoms.iter().map(|g| g.origin).collect(), d: geoms.iter().map(|g| g.dir).collect() };
            let e: Vec<f32> = cases.iter().flat_map(|c| c.0.clone()).collect();
            let raw: Vec<f32> = cases.iter().flat_map(|c| c.1.clone()).collect();
            let w = r.weights(&rays, geo, n, &e, &raw, 0.01);
            for i in 0..rays.len() {
                let wi = &w[i * n..(i + 1) * n];
                prop_assert!(wi.iter().all(|&x| x.is_finite() && (-1e-7..=1.0).contains(&x)), "{wi:?}");
                prop_assert!(wi.iter().sum::<f32>() <= 1.0 + 1e-5);
            }
            let (ne, pos) = r.pdf(&rays, geo, (n, 8), 0.7, true, &e, &w);
            for i in 0..rays.len() {
                let ei = &ne[i * 9..(i + 1) * 9];
                prop_assert!(ei.windows(2).all(|p| p[0] <= p[1]) && ei.iter().all(|&x| (0.0..=1.0).contains(&x)));
            }
            prop_assert!(pos.iter().all(|&x| (0.0..=1.0).contains(&x)), "positions in the unit cube");
            let c = CompositeCase {
                rays: rays.clone(),
                n,
                bands: 2,
                edges: e.clone(),
                raw: raw.clone(),
                colours: (0..rays.len() * n * 2).map(|k| (k % 11) as f32 / 10.0).collect(),
                targets: (0..rays.len()).flat_map(|k| [(k % 3) as f32 * 0.6 - 0.1, 0.5, 1.0]).collect(),
                band_w: vec![1.0, 1.0],
                background: None,
                geo,
                scale: 0.01,
            };
            let out = r.composite(&c, true);
            prop_assert!(out.d_raw.iter().chain(&out.d_colour).chain(&out.ray_out).all(|v| v.is_finite()));
            for i in 0..rays.len() {
                let a = out.ray_out[i * (RAY_OUT_FIXED + 2) + RayOut::Accumulation.col()]; // 2 bands
                prop_assert!((-1e-6..=1.0 + 1e-5).contains(&a), "accumulation {a}");
            }
            Ok(())
        })
        .unwrap_or_else(|e| panic!("{e}"));
}
