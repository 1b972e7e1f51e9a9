//! CPU twin of `glsl/encoding/sh_fwd.comp` and `sh_bwd.comp`: the degree-4 (16-value) real spherical-harmonics
//! basis in tiny-cuda-nn's convention (nerfacto.md §2.16), evaluated on the unit direction d itself (nerfstudio
//! maps d to (d+1)/2 before tcnn, which maps it back). The f32 instantiation follows the kernels' order of
//! operations; the f64 one is the accurate reference for finite differences.
//!
//! The backward is the gradient of the polynomials as written (x, y, z independent), not projected onto the
//! sphere: a caller that normalised the direction applies that chain rule itself.

// The coefficients are written digit for digit as in nerfacto.md §2.16 (and tcnn), to be checked against it.
#![allow(clippy::excessive_precision)]

use super::real::Real;

/// Number of SH values per direction (degree 4 = bands l = 0..3).
pub const SH_DIM: usize = 16;

pub const C0: f64 = 0.28209479177387814;
pub const C1: f64 = 0.48860251190291987;
pub const C4: f64 = 1.0925484305920792;
pub const C6: f64 = 0.94617469575755997;
pub const C6B: f64 = 0.31539156525251999;
pub const C8: f64 = 0.54627421529603959;
pub const C9: f64 = 0.59004358992664352;
pub const C10: f64 = 2.8906114426405538;
pub const C11: f64 = 0.45704579946446572;
pub const C12: f64 = 0.3731763325901154;
pub const C14: f64 = 1.4453057213202769;

/// The 16 basis values of one direction.
pub fn encode<T: Real>(d: [T; 3]) -> [T; SH_DIM] {
    let [x, y, z] = d;
    let c = T::c;
    let (xy, xz, yz) = (x * y, x * z, y * z);
    let (x2, y2, z2) = (x * x, y * y, z * z);
    [
        c(C0),
        -c(C1) * y,
        c(C1) * z,
        -c(C1) * x,
        c(C4) * xy,
        -c(C4) * yz,
        c(C6) * z2 - c(C6B),
        -c(C4) * xz,
        c(C8) * (x2 - y2),
        c(C9) * y * (y2 - c(3.0) * x2),
        c(C10) * xy * z,
        c(C11) * y * (c(1.0) - c(5.0) * z2),
        c(C12) * z * (c(5.0) * z2 - c(3.0)),
        c(C11) * x * (c(1.0) - c(5.0) * z2),
        c(C14) * z * (x2 - y2),
        c(C9) * x * (c(3.0) * y2 - x2),
    ]
}

/// dL/d(direction) given dL/d(SH values) `g`, for one direction.
pub fn grad<T: Real>(d: [T; 3], g: &[T; SH_DIM]) -> [T; 3] {
    let [x, y, z] = d;
    let c = T::c;
    let (xy, xz, yz) = (x * y, x * z, y * z);
    let (x2, y2, z2) = (x * x, y * y, z * z);
    let a = c(1.0) - c(5.0) * z2; // 1 - 5z^2
    let b = c(3.0 * C9) * (y2 - x2); // d(Y9)/dy = d(Y15)/dx
    let gx = g[3] * -c(C1)
        + g[4] * (c(C4) * y)
        + g[7] * (-c(C4) * z)
        + g[8] * (c(2.0 * C8) * x)
        + g[9] * (-c(6.0 * C9) * xy)
        + g[10] * (c(C10) * yz)
        + g[13] * (c(C11) * a)
        + g[14] * (c(2.0 * C14) * xz)
        + g[15] * b;
    let gy = g[1] * -c(C1)
        + g[4] * (c(C4) * x)
        + g[5] * (-c(C4) * z)
        + g[8] * (-c(2.0 * C8) * y)
        + g[9] * b
        + g[10] * (c(C10) * xz)
        + g[11] * (c(C11) * a)
        + g[14] * (-c(2.0 * C14) * yz)
        + g[15] * (c(6.0 * C9) * xy);
    let gz = g[2] * c(C1)
        + g[5] * (-c(C4) * y)
        + g[6] * (c(2.0 * C6) * z)
        + g[7] * (-c(C4) * x)
        + g[10] * (c(C10) * xy)
        + g[11] * (-c(10.0 * C11) * yz)
        + g[12] * (c(C12) * (c(15.0) * z2 - c(3.0)))
        + g[13] * (-c(10.0 * C11) * xz)
        + g[14] * (c(C14) * (x2 - y2));
    [gx, gy, gz]
}

/// Twin of `sh_fwd`: `out[i * row_stride + col + k] = Y_k(dirs[3i..3i+3])`; other columns are left alone.
pub fn sh_fwd<T: Real>(dirs: &[T], out: &mut [T], row_stride: usize, col: usize) {
    for (i, d) in dirs.chunks_exact(3).enumerate() {
        let y = encode([d[0], d[1], d[2]]);
        out[i * row_stride + col..i * row_stride + col + SH_DIM].copy_from_slice(&y);
    }
}

/// Twin of `sh_bwd`: `d_dirs[3i..3i+3] (+)= grad(dirs_i, d_sh row i)`.
pub fn sh_bwd<T: Real>(dirs: &[T], d_sh: &[T], row_stride: usize, col: usize, d_dirs: &mut [T], accumulate: bool) {
    for (i, d) in dirs.chunks_exact(3).enumerate() {
        let mut g = [T::ZERO; SH_DIM];
        g.copy_from_slice(&d_sh[i * row_stride + col..i * row_stride + col + SH_DIM]);
        let gd = grad([d[0], d[1], d[2]], &g);
        for k in 0..3 {
            d_dirs[3 * i + k] = if accumulate { d_dirs[3 * i + k] + gd[k] } else { gd[k] };
        }
    }
}
