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

/// Level `l`'s coarse-to-fine weight for `active` levels (`HashGrid::level_weight`): clamp(active - l, 0, 1).
pub fn level_weight<T: Float>(active: T, l: usize) -> T {
    (active - T::from(l).expect("level fits")).max(T::zero()).min(T::one())
}

/// Per-level weights for `active` levels (all ones for `active` >= L).
pub fn level_weights<T: Float>(n_levels: usize, active: T) -> Vec<T> {
    (0..n_levels).map(|l| level_weight(active, l)).collect()
}

/// Encoding of one point: L x F values, level-major.
pub fn forward<T: Float>(levels: &[HashLevel], f: usize, params: &[T], p: [T; 3]) -> Vec<T> {
    forward_weighted(levels, f, params, p, &vec![T::one(); levels.len()])
}

/// [`forward`] with each level's values multiplied by its coarse-to-fine weight (`weights[l]`).
pub fn forward_weighted<T: Float>(levels: &[HashLevel], f: usize, params: &[T], p: [T; 3], weights: &[T]) -> Vec<T> {
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
        for v in &mut out[l * f..(l + 1) * f] {
            *v = *v * weights[l];
        }
    }
    out
}

/// Adds d(encoding)/d(params)^T dy into `grads` for one point.
pub fn backward_params<T: Float>(levels: &[HashLevel], f: usize, p: [T; 3], dy: &[T], grads: &mut [T]) {
    backward_params_weighted(levels, f, p, dy, grads, &vec![T::one(); levels.len()])
}

/// [`backward_params`] of [`forward_weighted`]: level l's dy is multiplied by `weights[l]`.
pub fn backward_params_weighted<T: Float>(
    levels: &[HashLevel],
    f: usize,
    p: [T; 3],
    dy: &[T],
    grads: &mut [T],
    weights: &[T],
) {
    for (l, lv) in levels.iter().enumerate() {
        let (c0, frac) = cell(lv, p);
        for c in 0..8 {
            let (v, w) = corner(c, c0, frac);
            let base = param_index(lv, v, f);
            for k in 0..f {
                grads[base + k] = grads[base + k] + w * weights[l] * dy[l * f + k];
            }
        }
    }
}

/// dL/dp for one point.
pub fn backward_input<T: Float>(levels: &[HashLevel], f: usize, params: &[T], p: [T; 3], dy: &[T]) -> [T; 3] {
    backward_input_weighted(levels, f, params, p, dy, &vec![T::one(); levels.len()])
}

/// dL/dp of [`forward_weighted`] for one point.
pub fn backward_input_weighted<T: Float>(
    levels: &[HashLevel],
    f: usize,
    params: &[T],
    p: [T; 3],
    dy: &[T],
    weights: &[T],
) -> [T; 3] {
    let mut grad = [T::zero(); 3];
    for (l, lv) in levels.iter().enumerate() {
        let (c0, frac) = cell(lv, p);
        let scale = T::from(lv.scale).expect("f32 fits");
        for c in 0..8u32 {
            let (v, _) = corner(c, c0, frac);
            let base = param_index(lv, v, f);
            let gtheta = (0..f).fold(T::zero(), |acc, k| acc + weights[l] * dy[l * f + k] * params[base + k]);
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
