//! Stability of sample positions and the hash encoding: points at the world origin, on the contraction boundary
//! (|x|_inf = 1 exactly and one ulp either side), far outside it (up to 1e30), exactly on grid vertices, on the faces
//! of the unit cube, and the largest hash resolutions (max_resolution 2^19 with a 2^24 table, where the index
//! arithmetic lives at the edge of u32). GPU kernels against the f32 twin (same arithmetic: identical indices) and
//! the f64 twin. Tolerances: positions and f32-twin values |a-b| <= 1e-5 + 1e-4|b|; against the f64 twin the
//! encoding differs by fp32's rounding of q = p * scale + 0.5, bounded per level by 2 ulp(q) max|theta| (stated
//! where used).

use crate::common;
use crate::stability_support;
use common::gpu;
use msnerf::gpu::{Context, LargeArray, MemoryCategory};
use msnerf::nerf::kernels::Geometry;
use msnerf::nn::hashgrid::{HashGrid, HashGridConfig, HashLevel, OutputSlot};
use msnerf::nn::{ParamSlice, RowSlice};
use msnerf::reference::hashgrid as twin;
use msnerf::reference::render as tw;
use stability_support::*;

/// World points that stress the contraction; the twin's own continuity is checked across the boundary.
fn hard_points() -> Vec<[f32; 3]> {
    let below = 1.0f32 - f32::EPSILON / 2.0;
    let above = 1.0f32 + f32::EPSILON;
    vec![
        [0.0, 0.0, 0.0],     // world origin: the unused x/|x| branch would be 0/0
        [1.0, 0.0, 0.0],     // exactly on the contraction boundary
        [below, 0.3, -0.2],  // one ulp inside
        [above, 0.3, -0.2],  // one ulp outside
        [-1.0, -1.0, -1.0],  // boundary corner
        [1.0, 1.0, 1.0],     //
        [0.5, -1.0, 0.999],  // boundary face, other axis
        [1e6, -2e6, 3e6],    // far away: contracted to the cube face
        [1e30, 1e30, -1e30], // as far as fp32 goes comfortably
        [0.0, 0.0, 1e-40],   // a subnormal coordinate
        [-0.75, 0.25, 0.5],  // ordinary
    ]
}

/// Hash inputs of the hard points through `sample_initial` (near 0, far 1e-30: the single sample sits at the ray
/// origin to the last bit), against the f64 twin.
#[test]
fn contraction_at_the_origin_on_the_boundary_and_far_away_is_finite_and_continuous() {
    let g = gpu();
    let r = Render::new(&g);
    let pts = hard_points();
    let rays = Rays { o: pts.clone(), d: vec![[0.0, 0.0, 1.0]; pts.len()] };
    for contraction in [true, false] {
        let geo = Geometry { near: 0.0, far: 1e-30, contraction };
        let (_, pos) = r.sample_initial(&rays, geo, 1, false);
        assert_finite(&pos, "hash inputs");
        assert!(pos.iter().all(|v| (0.0..=1.0).contains(v)), "hash inputs in [0, 1]: {pos:?}");
        for (i, p) in pts.iter().enumerate() {
            // Without contraction, p = (x + 1)/2 rounds 1 - ulp to exactly 1 in fp32 (outside the box) but not in
            // f64: that point is compared with the f32 twin (the kernels' arithmetic), the rest with the f64 twin.
            let want = if contraction || i != 2 {
                tw::hash_input(p.map(|v| v as f64), contraction).0
            } else {
                tw::hash_input(*p, false).0.map(|v| v as f64)
            };
            check_vals(&pos[3 * i..3 * i + 3], &want, &format!("point {p:?} (contraction {contraction})"));
        }
        if contraction {
            assert_eq!(&pos[..3], &[0.5, 0.5, 0.5], "the origin maps to the grid centre");
            // Continuity across |x|_inf = 1: one ulp either side lands one ulp apart.
            assert!((pos[6] - pos[9]).abs() < 1e-6, "continuous at the boundary: {} vs {}", pos[6], pos[9]);
        }
    }
    // The twin in f64 around the boundary, and its limit far away.
    for x in [1.0 - 1e-12, 1.0, 1.0 + 1e-12] {
        let q = tw::contract([x, 0.5, 0.0f64]);
        assert!((q[0] - 1.0).abs() < 1e-11 && (q[1] - 0.5).abs() < 1e-11, "{x}: {q:?}");
    }
    let far = tw::contract([1e300, -1e300, 0.0f64]);
    assert!((far[0] - 2.0).abs() < 1e-12 && (far[1] + 2.0).abs() < 1e-12 && far[2] == 0.0, "{far:?}");
}

/// Parameters with a cheap deterministic pattern (a 128 MiB table is filled in ~0.1 s).
fn pattern(n: usize) -> Vec<f32> {
    (0..n).map(|i| ((i * 7919) % 4093) as f32 / 4093.0 - 0.5).collect()
}

struct Encoded {
    fwd: Vec<f32>,
    grads: Vec<f32>,
    dp: Vec<f32>,
    host: Vec<f32>,
}

/// Forward, parameter backward and input backward of `pts` (hash inputs) with dL/dy = 1 + 0.1 (level + feature).
fn encode(g: &Context, cfg: &HashGridConfig, pts: &[[f32; 3]]) -> Encoded {
    let grid = HashGrid::new(g, cfg).expect("grid");
    let np = cfg.n_params();
    let host = pattern(np);
    let params = LargeArray::<f32>::new(g, "params", np, MemoryCategory::Parameters).expect("params");
    params.upload(g, 0, &host).expect("upload");
    let grads = LargeArray::<f32>::new(g, "grads", np, MemoryCategory::Gradients).expect("grads");
    for c in grads.chunks() {
        let mut rec = g.recorder("zero").expect("rec");
        msnerf::ops::fill(&mut rec, c, 0.0f32, 0, c.len()).expect("zero");
        rec.submit_and_wait().expect("submit");
    }
    let n = pts.len();
    let w = cfg.n_output();
    let pos = up(g, "pos", &pts.concat());
    let out = zeros(g, "out", n * w);
    let dyv: Vec<f32> = (0..n * w).map(|i| 1.0 + 0.1 * (i % w) as f32).collect();
    let dy = up(g, "dy", &dyv);
    let dp = zeros(g, "dp", 3 * n);
    let mut rec = g.recorder("enc").expect("rec");
    let ps = ParamSlice { array: &params, offset: 0 };
    grid.forward(&mut rec, ps, &pos, n, &out, OutputSlot { stride: w, col: 0, pad_to: w, pad_value: 0.0 })
        .expect("fwd");
    let rows = RowSlice { buf: &dy, stride: w, col: 0 };
    grid.backward_params(&mut rec, ParamSlice { array: &grads, offset: 0 }, &pos, n, rows).expect("bwd");
    grid.backward_input(&mut rec, ps, &pos, n, rows, &dp).expect("bwd input");
    rec.submit_and_wait().expect("submit");
    Encoded {
        fwd: g.download(&out).expect("out"),
        grads: grads.download(g).expect("grads"),
        dp: g.download(&dp).expect("dp"),
        host,
    }
}

/// Compares an encoding run with the f32 twin (every value and every touched gradient entry) and, for the forward,
/// with the f64 twin within fp32's rounding of q.
fn check_encoding(cfg: &HashGridConfig, pts: &[[f32; 3]], e: &Encoded, what: &str) {
    let levels = cfg.levels();
    let f = cfg.features_per_level as usize;
    let w = cfg.n_output();
    assert_finite(&e.fwd, &format!("{what}: forward"));
    assert_finite(&e.dp, &format!("{what}: dL/dp"));
    let host64: Vec<f64> = f64s(&e.host);
    let mut want_g = vec![0.0f32; e.host.len()];
    for (i, p) in pts.iter().enumerate() {
        let dy: Vec<f32> = (0..w).map(|k| 1.0 + 0.1 * k as f32).collect();
        let want = twin::forward(&levels, f, &e.host, *p);
        check_vals(&e.fwd[i * w..(i + 1) * w], &f64s(&want), &format!("{what}: point {p:?} forward vs f32 twin"));
        let want64 = twin::forward(&levels, f, &host64, p.map(|v| v as f64));
        for (l, lv) in levels.iter().enumerate() {
            // q = p scale + 0.5 is rounded to fp32: each corner weight moves by up to ~2 ulp(q), times max|theta| = 0.5.
            let tol = 2.0 * (lv.scale as f64 + 1.0) * f32::EPSILON as f64 * 0.5 * 8.0 + 1e-6;
            for k in 0..f {
                let (a, b) = (e.fwd[i * w + l * f + k] as f64, want64[l * f + k]);
                assert!((a - b).abs() <= tol, "{what}: point {p:?} level {l}: {a} vs f64 {b} (tol {tol:e})");
            }
        }
        let dp = twin::backward_input(&levels, f, &e.host, *p, &dy);
        check_vals(&e.dp[3 * i..3 * i + 3], &f64s(&dp), &format!("{what}: point {p:?} dL/dp vs f32 twin"));
        twin::backward_params(&levels, f, *p, &dy, &mut want_g);
    }
    assert_finite(&e.grads, &format!("{what}: parameter gradients"));
    let touched: Vec<usize> = (0..want_g.len()).filter(|&i| want_g[i] != 0.0 || e.grads[i] != 0.0).collect();
    assert!(!touched.is_empty());
    for &i in &touched {
        let (a, b) = (e.grads[i], want_g[i]);
        assert!(common::close(a as f64, b as f64, 1e-5, 1e-4), "{what}: gradient entry {i}: {a} vs {b}");
    }
}

/// The largest index any kernel forms for a grid at float offset `param_offset`: ((offset + entries) F + offset)
/// in exact arithmetic, which must stay below 2^32 (the kernels compute it in u32).
fn max_float_index(levels: &[HashLevel], f: u32, param_offset: u64) -> u64 {
    levels.iter().map(|l| (l.offset as u64 + l.entries as u64) * f as u64 + param_offset).max().unwrap_or(0)
}

/// Points exactly on grid vertices (frac = 0: corner weights 0 and 1, the input gradient's one-sided kink), on the
/// faces of the unit cube (q = 0.5 and q = scale + 0.5, whose +1 corner equals res and wraps modulo the dense level
/// as in tcnn), a hair outside it (contraction rounding; q is clamped at 0 so the u32 cell cannot wrap), and the
/// grid centre (the world origin).
#[test]
fn grid_vertices_cube_faces_and_the_origin_encode_like_the_twin() {
    let g = gpu();
    let cfg = HashGridConfig {
        n_levels: 6,
        features_per_level: 2,
        log2_hashmap_size: 12,
        base_resolution: 16,
        max_resolution: 128,
    };
    let levels = cfg.levels();
    let s0 = levels[0].scale; // 15: p = (k - 0.5) / 15 is a vertex of level 0
    let on_vertex = |k: f32| (k - 0.5) / s0;
    let pts = vec![
        [0.5, 0.5, 0.5],
        [on_vertex(1.0), on_vertex(7.0), on_vertex(15.0)],
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [0.0, 1.0, 0.5],
        [-1e-7, 0.5, 1.0 + 1e-7],
        [0.25, 0.75, 0.333_333_34],
    ];
    for p in &pts[..2] {
        for d in 0..3 {
            let q = p[d] * s0 + 0.5;
            assert_eq!(q, q.floor(), "{p:?} is on a level-0 vertex");
        }
    }
    let e = encode(&g, &cfg, &pts);
    check_encoding(&cfg, &pts, &e, "vertices and faces");
}

/// The largest hash resolutions: max_resolution 2^19 with a 2^24-entry table (tcnn's maximum). The hashed level's
/// vertex coordinates reach 2^19 and the CoherentPrime products wrap u32 exactly as tcnn's do; since the table is a
/// power of two, masking the wrapped product gives the same index as exact arithmetic. The float index
/// (offset + entry) x F + f is formed in u32: for every grid `HashGridConfig::validate` accepts (at most 32 levels x
/// 8 features x 2^24 entries = 2^32 floats) it stays below 2^32, which this test checks on the largest one. What
/// would break past that: the index wraps and silently aliases another level's parameters.
#[test]
fn largest_hash_resolution_keeps_u32_indices_exact() {
    // Index bounds of big configurations: nerfacto-huge-like 16 levels x 2^24, and the largest accepted grid (every
    // level hashed: base resolution 256 already exceeds 2^24 vertices).
    for (l, f, base) in [(2u32, 2u32, 16u32), (16, 2, 16), (16, 8, 16), (32, 8, 16), (32, 8, 256)] {
        let cfg = HashGridConfig {
            n_levels: l,
            features_per_level: f,
            log2_hashmap_size: 24,
            base_resolution: base,
            max_resolution: 1 << 19,
        };
        assert!(cfg.validate().is_ok(), "{cfg:?}");
        let levels = cfg.levels();
        let top = levels.last().unwrap();
        assert!(top.res >= 1 << 19 && top.hashed == 1 && top.entries == 1 << 24, "{top:?}");
        let max_index = max_float_index(&levels, f, 0) - 1;
        assert!(max_index < 1 << 32, "{l} levels x {f} features: largest float index {max_index}");
        assert_eq!(cfg.n_params() as u64, max_index + 1);
    }
    assert!(HashGridConfig {
        n_levels: 33,
        features_per_level: 8,
        log2_hashmap_size: 24,
        base_resolution: 256,
        max_resolution: 1 << 19
    }
    .validate()
    .is_err());
    // The GPU at 2 levels (16^3 dense, then 2^19 hashed into 2^24 entries: 128 MiB of parameters).
    let g = gpu();
    let cfg = HashGridConfig {
        n_levels: 2,
        features_per_level: 2,
        log2_hashmap_size: 24,
        base_resolution: 16,
        max_resolution: 1 << 19,
    };
    let levels = cfg.levels();
    assert_eq!((levels[1].entries, levels[1].offset, levels[1].hashed), (1 << 24, 4096, 1));
    let top = levels[1].scale;
    let pts = vec![
        [1.0, 1.0, 1.0], // vertex coordinate 2^19 on every axis: the largest products
        [0.0, 0.0, 0.0],
        [0.5, 0.5, 0.5], // q = 262144 exactly: on a vertex
        [0.999_999_9, 0.000_000_1, 0.75],
        [(top - 1.5) / top, 0.123_456_7, 0.987_654_3],
        [0.333, 0.666, 0.999],
    ];
    // Exact-arithmetic indices of every corner equal the u32 ones (the table is a power of two).
    for p in &pts {
        for x in p {
            let q = (x * top + 0.5).max(0.0);
            let c = q.floor() as u64;
            assert!(c <= 1 << 19, "vertex coordinate {c} in range");
        }
        let v = [p[0], p[1], p[2]].map(|x| ((x * top + 0.5).max(0.0).floor() as u64) + 1);
        let exact = (v[0] ^ (v[1] * 2_654_435_761) ^ (v[2] * 805_459_861)) & ((1 << 24) - 1);
        let wrapped =
            (v[0] as u32 ^ (v[1] as u32).wrapping_mul(2_654_435_761) ^ (v[2] as u32).wrapping_mul(805_459_861))
                & ((1 << 24) - 1);
        assert_eq!(exact, wrapped as u64, "u32 wrap-around is exact modulo the table");
    }
    let e = encode(&g, &cfg, &pts);
    check_encoding(&cfg, &pts, &e, "2^19 / 2^24 grid");
}
