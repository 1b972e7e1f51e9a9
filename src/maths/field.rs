//! The scene contraction (nerfstudio's L-infinity `SceneContraction`) and the hash-grid input of a point, with the
//! gradient through them: the maths of `contract`, `hash_input` and `hash_input_grad` in the GLSL kernels
//! (glsl/render, glsl/pose/pose_common.glsl).

use super::{c, dot};
use num_traits::Float;

pub fn contract<T: Float>(x: [T; 3]) -> [T; 3] {
    let m = x[0].abs().max(x[1].abs()).max(x[2].abs());
    if m < T::one() {
        return x;
    }
    let k = (c::<T>(2.0) - T::one() / m) / m;
    [x[0] * k, x[1] * k, x[2] * k]
}

/// Hash-grid input and whether the point carries density.
pub fn hash_input<T: Float>(x: [T; 3], contraction: bool) -> ([T; 3], bool) {
    if contraction {
        let q = contract(x);
        return (q.map(|v| (v + c(2.0)) * c(0.25)), true);
    }
    let p = x.map(|v| (v + T::one()) * c(0.5));
    let inside = p.iter().all(|&v| v > T::zero() && v < T::one());
    (if inside { p } else { [T::zero(); 3] }, inside)
}

/// dL/dx of a world point given dL/dh of its hash input (`render::hash_input`), as `hash_input_grad` in the kernels.
pub fn hash_input_grad<T: Float>(x: [T; 3], gh: [T; 3], contraction: bool) -> [T; 3] {
    if !contraction {
        let inside = hash_input(x, false).1;
        return if inside { gh.map(|v| c::<T>(0.5) * v) } else { [T::zero(); 3] };
    }
    let g = gh.map(|v| c::<T>(0.25) * v);
    let ax = x.map(|v| v.abs());
    let m = ax[0].max(ax[1]).max(ax[2]);
    if m < T::one() {
        return g;
    }
    let k = (c::<T>(2.0) - T::one() / m) / m;
    let dk = c::<T>(2.0) * (T::one() - m) / (m * m * m);
    let j = if ax[0] == m {
        0
    } else if ax[1] == m {
        1
    } else {
        2
    };
    let mut out = g.map(|v| k * v);
    out[j] = out[j] + x[j].signum() * dk * dot(x, g);
    out
}
