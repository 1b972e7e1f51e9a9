//! SH direction encoding (`sh_fwd`, `sh_bwd`) against its CPU twin (`msnerf::reference::sh`), the basis against
//! the spec's coefficients and orthonormality, and the backward against central finite differences of the f64
//! twin. Tolerance: fp32 |a-b| <= 1e-5 + 1e-4|b|.

// Spec coefficients are written digit for digit; index loops mirror the maths.
#![allow(clippy::excessive_precision, clippy::needless_range_loop)]

use crate::common;
use common::{assert_all_close_f32, close, gpu, rng};
use msnerf::gpu::{Context, GpuBuffer, MemoryCategory};
use msnerf::nn::sh::{self, RowLayout, SH_DIM};
use msnerf::reference::sh as twin;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Not a multiple of the 64-wide workgroup.
const N: usize = 1_037;

fn buf(g: &Context, name: &str, data: &[f32]) -> GpuBuffer<f32> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Other, data).expect("upload")
}

/// Uniform unit directions (normalised Gaussians), as f64.
fn unit_dirs(r: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(3 * n);
    while out.len() < 3 * n {
        let v: [f64; 3] = [r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), r.random_range(-1.0..1.0)];
        let l2 = v.iter().map(|x| x * x).sum::<f64>();
        if l2 > 1e-4 && l2 <= 1.0 {
            out.extend(v.iter().map(|x| x / l2.sqrt()));
        }
    }
    out
}

fn to_f32(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}

fn encode_gpu(g: &Context, dirs: &[f32], layout: RowLayout, fill: f32) -> Vec<f32> {
    let n = dirs.len() / 3;
    let d = buf(g, "dirs", dirs);
    let out = buf(g, "sh out", &vec![fill; n * layout.row_stride]);
    let mut rec = g.recorder("sh fwd").expect("recorder");
    sh::sh_fwd(&mut rec, &d, n, &out, layout).expect("sh_fwd");
    rec.submit_and_wait().expect("submit");
    g.download(&out).expect("download")
}

#[test]
fn basis_matches_the_spec_at_the_poles() {
    // d = +z: only the zonal terms survive (nerfacto.md §2.16).
    let y = twin::encode([0.0f64, 0.0, 1.0]);
    let mut want = [0.0; SH_DIM];
    want[0] = 0.28209479177387814;
    want[2] = 0.48860251190291987;
    want[6] = 0.94617469575755997 - 0.31539156525251999;
    want[12] = 0.3731763325901154 * 2.0;
    for k in 0..SH_DIM {
        assert!((y[k] - want[k]).abs() < 1e-15, "Y{k}(+z) = {} want {}", y[k], want[k]);
    }
    // d = +x: Y3 = -C1 (tcnn's sign convention), Y8 = C8, Y13 = C11, Y15 = -C9.
    let y = twin::encode([1.0f64, 0.0, 0.0]);
    assert_eq!(y[3], -0.48860251190291987);
    assert_eq!(y[8], 0.54627421529603959);
    assert_eq!(y[13], 0.45704579946446572);
    assert_eq!(y[15], -0.59004358992664352);
    // d = (1,1,1)/sqrt(3): Y10 = C10 / 3^1.5.
    let s = 1.0 / 3f64.sqrt();
    let y = twin::encode([s, s, s]);
    assert!((y[10] - 2.8906114426405538 / 3f64.powf(1.5)).abs() < 1e-15);
}

#[test]
fn forward_matches_twin_into_a_wide_row() {
    let g = gpu();
    let mut r = rng(11);
    let dirs = to_f32(&unit_dirs(&mut r, N));
    for layout in [RowLayout::DENSE, RowLayout { row_stride: 64, col: 0 }, RowLayout { row_stride: 64, col: 37 }] {
        let got = encode_gpu(&g, &dirs, layout, -7.0);
        let mut want = vec![-7.0f32; N * layout.row_stride];
        twin::sh_fwd(&dirs, &mut want, layout.row_stride, layout.col);
        assert_all_close_f32(&got, &want, &format!("sh_fwd {layout:?}"));
        // Columns outside [col, col + 16) keep their contents exactly.
        for (i, v) in got.iter().enumerate() {
            let c = i % layout.row_stride;
            if c < layout.col || c >= layout.col + SH_DIM {
                assert_eq!(*v, -7.0, "sh_fwd {layout:?} wrote outside its columns at {i}");
            }
        }
    }
    // The f32 twin stays close to the f64 one.
    let d64 = unit_dirs(&mut r, 100);
    for d in d64.chunks_exact(3) {
        let a = twin::encode([d[0] as f32, d[1] as f32, d[2] as f32]);
        let b = twin::encode([d[0], d[1], d[2]]);
        assert!((0..SH_DIM).all(|k| close(a[k] as f64, b[k], 1e-6, 1e-5)));
    }
}

#[test]
fn basis_is_orthonormal_monte_carlo() {
    // 4π E[Y_i Y_j] over uniform directions ~ δ_ij, with the GPU's own f32 values.
    let g = gpu();
    let mut r = rng(12);
    let n = 200_003;
    let dirs = to_f32(&unit_dirs(&mut r, n));
    let y = encode_gpu(&g, &dirs, RowLayout::DENSE, 0.0);
    let mut gram = [[0.0f64; SH_DIM]; SH_DIM];
    for row in y.chunks_exact(SH_DIM) {
        for i in 0..SH_DIM {
            for j in 0..=i {
                gram[i][j] += row[i] as f64 * row[j] as f64;
            }
        }
    }
    let scale = 4.0 * std::f64::consts::PI / n as f64;
    for i in 0..SH_DIM {
        for j in 0..=i {
            let v = gram[i][j] * scale;
            let want = if i == j { 1.0 } else { 0.0 };
            // Monte-Carlo standard error is below 0.01 for every pair at this n.
            assert!((v - want).abs() < 0.04, "<Y{i}, Y{j}> = {v}, want {want}");
        }
    }
}

#[test]
fn backward_matches_twin_and_accumulates() {
    let g = gpu();
    let mut r = rng(13);
    let dirs = to_f32(&unit_dirs(&mut r, N));
    let layout = RowLayout { row_stride: 48, col: 20 };
    let d_sh: Vec<f32> = (0..N * layout.row_stride).map(|_| r.random_range(-1.0..1.0)).collect();
    let prior: Vec<f32> = (0..3 * N).map(|_| r.random_range(-1.0..1.0)).collect();
    let (dd, dsh) = (buf(&g, "dirs", &dirs), buf(&g, "d_sh", &d_sh));
    let (over, acc) = (buf(&g, "d_dirs overwrite", &prior), buf(&g, "d_dirs accumulate", &prior));
    let mut rec = g.recorder("sh bwd").expect("recorder");
    sh::sh_bwd(&mut rec, &dd, N, &dsh, layout, &over, false).expect("sh_bwd");
    sh::sh_bwd(&mut rec, &dd, N, &dsh, layout, &acc, true).expect("sh_bwd accumulate");
    rec.submit_and_wait().expect("submit");
    let mut want = prior.clone();
    twin::sh_bwd(&dirs, &d_sh, layout.row_stride, layout.col, &mut want, false);
    assert_all_close_f32(&g.download(&over).expect("download"), &want, "sh_bwd");
    let mut want = prior.clone();
    twin::sh_bwd(&dirs, &d_sh, layout.row_stride, layout.col, &mut want, true);
    assert_all_close_f32(&g.download(&acc).expect("download"), &want, "sh_bwd accumulate");
}

/// Central differences of L(d) = Σ_k w_k Y_k(d) with the f64 twin.
fn fd_grad(d: [f64; 3], w: &[f64; SH_DIM]) -> [f64; 3] {
    let h = 1e-6;
    let loss = |d: [f64; 3]| twin::encode(d).iter().zip(w).map(|(y, w)| y * w).sum::<f64>();
    let mut out = [0.0; 3];
    for j in 0..3 {
        let (mut a, mut b) = (d, d);
        a[j] += h;
        b[j] -= h;
        out[j] = (loss(a) - loss(b)) / (2.0 * h);
    }
    out
}

#[test]
fn backward_matches_finite_differences() {
    let g = gpu();
    let mut r = rng(14);
    let n = 300;
    let dirs64 = unit_dirs(&mut r, n);
    let w64: Vec<f64> = (0..n * SH_DIM).map(|_| r.random_range(-1.0..1.0)).collect();
    let fd: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let d = [dirs64[3 * i], dirs64[3 * i + 1], dirs64[3 * i + 2]];
            fd_grad(d, w64[i * SH_DIM..(i + 1) * SH_DIM].try_into().expect("16"))
        })
        .collect();
    // The f64 twin's analytic gradient: tight.
    for i in 0..n {
        let d = [dirs64[3 * i], dirs64[3 * i + 1], dirs64[3 * i + 2]];
        let a = twin::grad(d, w64[i * SH_DIM..(i + 1) * SH_DIM].try_into().expect("16"));
        for j in 0..3 {
            assert!(close(a[j], fd[i][j], 1e-8, 1e-7), "twin grad {i}.{j}: {} vs fd {}", a[j], fd[i][j]);
        }
    }
    // The kernel (f32 inputs: finite differences taken at the f32-rounded direction).
    let dirs = to_f32(&dirs64);
    let w = to_f32(&w64);
    let (dd, dsh) = (buf(&g, "dirs", &dirs), buf(&g, "d_sh", &w));
    let out = buf(&g, "d_dirs", &vec![0.0; 3 * n]);
    let mut rec = g.recorder("sh bwd fd").expect("recorder");
    sh::sh_bwd(&mut rec, &dd, n, &dsh, RowLayout::DENSE, &out, false).expect("sh_bwd");
    rec.submit_and_wait().expect("submit");
    let got = g.download(&out).expect("download");
    for i in 0..n {
        let d = [dirs[3 * i] as f64, dirs[3 * i + 1] as f64, dirs[3 * i + 2] as f64];
        let wi: Vec<f64> = w[i * SH_DIM..(i + 1) * SH_DIM].iter().map(|&v| v as f64).collect();
        let want = fd_grad(d, wi.as_slice().try_into().expect("16"));
        for j in 0..3 {
            assert!(
                close(got[3 * i + j] as f64, want[j], 1e-5, 1e-4),
                "kernel {i}.{j}: {} vs fd {}",
                got[3 * i + j],
                want[j]
            );
        }
    }
}

#[test]
fn bad_layouts_are_refused() {
    let g = gpu();
    let d = buf(&g, "dirs", &[0.0, 0.0, 1.0, 1.0, 0.0, 0.0]);
    let small = buf(&g, "small", &[0.0; 40]);
    let mut rec = g.recorder("bad").expect("recorder");
    assert!(sh::sh_fwd(&mut rec, &d, 2, &small, RowLayout { row_stride: 16, col: 1 }).is_err(), "col + 16 > stride");
    assert!(sh::sh_fwd(&mut rec, &d, 2, &small, RowLayout { row_stride: 32, col: 0 }).is_err(), "rows overrun");
    assert!(sh::sh_fwd(&mut rec, &d, 3, &small, RowLayout::DENSE).is_err(), "too few directions");
    sh::sh_fwd(&mut rec, &d, 2, &small, RowLayout { row_stride: 20, col: 4 }).expect("fits exactly");
    rec.submit_and_wait().expect("submit");
}
