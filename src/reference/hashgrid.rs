//! CPU twin of the hash grid kernels (`glsl/encoding/hashgrid_*.comp`), generic over f32 (compared with the
//! kernels) and f64 (the reference for finite differences). Same index math as the GLSL, in u32 wrap-around.

use crate::nn::hashgrid::HashLevel;
use num_traits::Float;

fn hash_index(lv: &HashLevel, v: [u32; 3]) -> u32 {
    if lv.hashed != 0 {
        let h = v[0] ^ v[1].wrapping_mul(2_654_435_761) ^ v[2].wrapping_mul(805_459_861);
        return h & (lv.entries - 1);
    }
    v[0].wrapping_add(v[1].wrapping_mul(lv.res)).wrapping_add(v[2].wrapping_mul(lv.res).wrapping_mul(lv.res))
        % lv.entries
}

fn cell<T: Float>(lv: &HashLevel, p: [T; 3]) -> ([u32; 3], [T; 3]) {
    let scale = T::from(lv.scale).expect("f32 fits");
    let half = T::from(0.5).expect("0.5");
    let mut c = [0u32; 3];
    let mut f = [T::zero(); 3];
    for d in 0..3 {
        let q = (p[d] * scale + half).max(T::zero());
        let fl = q.floor();
        c[d] = fl.to_u32().unwrap_or(u32::MAX);
        f[d] = q - fl;
    }
    (c, f)
}

fn corner<T: Float>(c: u32, cell: [u32; 3], frac: [T; 3]) -> ([u32; 3], T) {
    let mut w = T::one();
    let mut v = cell;
    for d in 0..3 {
        let bit = (c >> d) & 1;
        v[d] = v[d].wrapping_add(bit);
        w = w * if bit == 1 { frac[d] } else { T::one() - frac[d] };
    }
    (v, w)
}

/// Entry index (from the grid's first float) of corner `c` at level `lv`.
fn param_index(lv: &HashLevel, v: [u32; 3], f: usize) -> usize {
    (lv.offset + hash_index(lv, v)) as usize * f
}

/// Encoding of one point: L x F values, level-major.
pub fn forward<T: Float>(levels: &[HashLevel], f: usize, params: &[T], p: [T; 3]) -> Vec<T> {
    let mut out = vec![T::zero(); levels.len() * f];
    for (l, lv) in levels.iter().enumerate() {
        let (c0, frac) = cell(lv, p);
        for c in 0..8 {
            let (v, w) = corner(c, c0, frac);
            let base = param_index(lv, v, f);
            for k in 0..f {
                out[l * f + k] = out[l * f + k] + w * params[base + k];
            }
        }
    }
    out
}

/// Adds d(encoding)/d(params)^T dy into `grads` for one point.
pub fn backward_params<T: Float>(levels: &[HashLevel], f: usize, p: [T; 3], dy: &[T], grads: &mut [T]) {
    for (l, lv) in levels.iter().enumerate() {
        let (c0, frac) = cell(lv, p);
        for c in 0..8 {
            let (v, w) = corner(c, c0, frac);
            let base = param_index(lv, v, f);
            for k in 0..f {
                grads[base + k] = grads[base + k] + w * dy[l * f + k];
            }
        }
    }
}

/// dL/dp for one point.
pub fn backward_input<T: Float>(levels: &[HashLevel], f: usize, params: &[T], p: [T; 3], dy: &[T]) -> [T; 3] {
    let mut grad = [T::zero(); 3];
    for (l, lv) in levels.iter().enumerate() {
        let (c0, frac) = cell(lv, p);
        let scale = T::from(lv.scale).expect("f32 fits");
        for c in 0..8u32 {
            let (v, _) = corner(c, c0, frac);
            let base = param_index(lv, v, f);
            let gtheta = (0..f).fold(T::zero(), |acc, k| acc + dy[l * f + k] * params[base + k]);
            for (d, g) in grad.iter_mut().enumerate() {
                let mut w = if (c >> d) & 1 == 1 { T::one() } else { -T::one() };
                for e in (0..3).filter(|&e| e != d) {
                    w = w * if (c >> e) & 1 == 1 { frac[e] } else { T::one() - frac[e] };
                }
                *g = *g + w * gtheta * scale;
            }
        }
    }
    grad
}
