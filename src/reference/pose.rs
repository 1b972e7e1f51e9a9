//! CPU twin of the camera pose refinement kernels (`glsl/pose/*.comp`, spec/nerfacto.md §2.4): nerfstudio's SO3xR3
//! correction p = [t, w] per camera (origin + t, direction rotated by exp(w)), the gradient of one sampling level
//! with respect to a ray's origin and direction, the per-camera reduction and the regulariser. Generic over f32
//! (compared with the kernels) and f64 (finite differences).

use super::real::Real;
use super::render::edge_to_t;
use super::sh;
pub use crate::maths::field::hash_input_grad;
pub use crate::maths::so3::{rotate, so3_coeffs};
use crate::maths::{c, cross, dot};
use num_traits::Float;

fn axpy<T: Float>(a: T, x: [T; 3], y: [T; 3]) -> [T; 3] {
    [0, 1, 2].map(|k| a * x[k] + y[k])
}

/// dL/dw of R(w) d given g = dL/d(R d).
pub fn rotate_grad_w<T: Float>(w: [T; 3], d: [T; 3], g: [T; 3]) -> [T; 3] {
    let (a, b, da, db) = so3_coeffs(w);
    let u = cross(w, d);
    let v = cross(w, u);
    let (wd, gw, gd) = (dot(w, d), dot(g, w), dot(g, d));
    let dg = cross(d, g);
    let s = da * dot(g, u) + db * dot(g, v);
    [0, 1, 2].map(|k| a * dg[k] + b * (g[k] * wd + d[k] * gw - c::<T>(2.0) * w[k] * gd) + s * w[k])
}

/// The corrected ray of camera correction `p` = [t, w]: (origin + t, R(w) direction).
pub fn apply<T: Float>(p: &[T], origin: [T; 3], dir: [T; 3]) -> ([T; 3], [T; 3]) {
    let w = [p[3], p[4], p[5]];
    ([0, 1, 2].map(|k| origin[k] + p[k]), rotate(w, dir))
}

/// One ray's (dL/dorigin, dL/ddirection) from one level: samples at the midpoints of `edges` (s-space), `dpos`
/// the hash-input gradients (3 per sample); `dsh` the sum over the ray's samples of dL/dSH (NeRF level only).
#[allow(clippy::too_many_arguments)]
pub fn ray_grad<T: Float + Real>(
    origin: [T; 3],
    dir: [T; 3],
    edges: &[T],
    (near, far, contraction): (T, T, bool),
    dpos: &[T],
    dsh: Option<&[T; sh::SH_DIM]>,
) -> ([T; 3], [T; 3]) {
    let mut g_o = [T::zero(); 3];
    let mut g_d = [T::zero(); 3];
    let mut t0 = edge_to_t(edges[0], near, far);
    for i in 0..edges.len() - 1 {
        let t1 = edge_to_t(edges[i + 1], near, far);
        let tm = c::<T>(0.5) * (t0 + t1);
        t0 = t1;
        let gh = [dpos[3 * i], dpos[3 * i + 1], dpos[3 * i + 2]];
        if gh.iter().all(|v| *v == T::zero()) {
            continue;
        }
        let x = axpy(tm, dir, origin);
        let gx = hash_input_grad(x, gh, contraction);
        g_o = axpy(T::one(), gx, g_o);
        g_d = axpy(tm, gx, g_d);
    }
    if let Some(g) = dsh {
        g_d = axpy(T::one(), sh::grad(dir, g), g_d);
    }
    (g_o, g_d)
}

/// The gradient of a camera's correction [t, w] from one ray's (g_o, g_d) and its uncorrected direction.
pub fn camera_grad<T: Float>(w: [T; 3], raw_dir: [T; 3], g_o: [T; 3], g_d: [T; 3]) -> [T; 6] {
    let gw = rotate_grad_w(w, raw_dir, g_d);
    [g_o[0], g_o[1], g_o[2], gw[0], gw[1], gw[2]]
}

/// The regulariser trans_weight * mean |t| + rot_weight * mean |w| over `n_train` cameras: per-camera loss shares
/// and the gradient (6 per camera; 0 where a norm is 0).
pub fn regularizer<T: Float>(poses: &[T], n_train: usize, trans_weight: T, rot_weight: T) -> (Vec<T>, Vec<T>) {
    let inv = T::one() / T::from(n_train.max(1)).expect("count fits");
    let (wt, wr) = (trans_weight * inv, rot_weight * inv);
    let mut losses = Vec::new();
    let mut grads = vec![T::zero(); poses.len()];
    for (cam, p) in poses.chunks(6).enumerate() {
        let nt = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let nw = (p[3] * p[3] + p[4] * p[4] + p[5] * p[5]).sqrt();
        losses.push(wt * nt + wr * nw);
        for k in 0..3 {
            if nt > T::zero() {
                grads[6 * cam + k] = wt * p[k] / nt;
            }
            if nw > T::zero() {
                grads[6 * cam + 3 + k] = wr * p[3 + k] / nw;
            }
        }
    }
    (losses, grads)
}
