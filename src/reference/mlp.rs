//! CPU twin of the fused MLP kernels (`glsl/network/mlp_*.comp`), generic over f32 and f64. With
//! `half_activations` the hidden activations are rounded to fp16 (round to nearest even) as the kernels store them.

use crate::nn::mlp::{Activation, MlpConfig};
use num_traits::Float;

fn act<T: Float>(a: Activation, x: T) -> T {
    match a {
        Activation::None => x,
        Activation::Sigmoid => T::one() / (T::one() + (-x).exp()),
        Activation::Exponential => x.exp(),
        Activation::Relu => x.max(T::zero()),
    }
}

fn act_grad<T: Float>(a: Activation, y: T) -> T {
    match a {
        Activation::None => T::one(),
        Activation::Sigmoid => y * (T::one() - y),
        Activation::Exponential => {
            let lo = T::from(-15.0f64).expect("f").exp();
            let hi = T::from(15.0f64).expect("f").exp();
            y.max(lo).min(hi)
        }
        Activation::Relu => {
            if y > T::zero() {
                T::one()
            } else {
                T::zero()
            }
        }
    }
}

/// A hidden activation as stored: itself, or rounded to fp16.
fn stored<T: Float>(c: &MlpConfig, v: T) -> T {
    if c.half_activations {
        let h = half::f16::from_f64(v.to_f64().expect("finite")).to_f64();
        T::from(h).expect("f16 fits")
    } else {
        v
    }
}

/// Forward of one row: (hidden post-ReLU activations per layer, outputs (n_output)). `x` has in_pad values.
pub fn forward<T: Float>(c: &MlpConfig, w: &[T], x: &[T]) -> (Vec<Vec<T>>, Vec<T>) {
    let mut a = x.to_vec();
    let mut hidden = Vec::new();
    let mut off = 0;
    let mats = c.matrices();
    for (m, &(rows, cols)) in mats.iter().enumerate() {
        let last = m + 1 == mats.len();
        let out: Vec<T> = (0..rows)
            .map(|j| {
                let s = (0..cols).fold(T::zero(), |acc, k| acc + w[off + j * cols + k] * a[k]);
                if last {
                    act(c.output_activation, s)
                } else {
                    stored(c, s.max(T::zero()))
                }
            })
            .collect();
        off += rows * cols;
        if !last {
            hidden.push(out.clone());
        }
        a = out;
    }
    a.truncate(c.n_output);
    (hidden, a)
}

/// Backward of one row: adds dL/dW into `grads`, returns dL/dx (in_pad values).
pub fn backward<T: Float>(c: &MlpConfig, w: &[T], x: &[T], dy: &[T], grads: &mut [T]) -> Vec<T> {
    let (hidden, y) = forward(c, w, x);
    backward_from(c, w, x, (&hidden, &y), dy, grads)
}

/// [`backward`] from a given forward pass: `hidden` and `y` as [`forward`] returns them, or as a kernel stored them
/// (its ReLU masks and output activations then decide, which is how the fp16-operand kernels are checked).
pub fn backward_from<T: Float>(
    c: &MlpConfig,
    w: &[T],
    x: &[T],
    (hidden, y): (&[Vec<T>], &[T]),
    dy: &[T],
    grads: &mut [T],
) -> Vec<T> {
    let mats = c.matrices();
    let mut offs = Vec::with_capacity(mats.len());
    let mut o = 0;
    for &(r, cc) in &mats {
        offs.push(o);
        o += r * cc;
    }
    // Output delta (padding columns zero).
    let mut delta: Vec<T> = (0..c.out_pad())
        .map(|j| if j < c.n_output { dy[j] * act_grad(c.output_activation, y[j]) } else { T::zero() })
        .collect();
    for m in (0..mats.len()).rev() {
        let (rows, cols) = mats[m];
        let input: &[T] = if m == 0 { x } else { &hidden[m - 1] };
        for j in 0..rows {
            for k in 0..cols {
                grads[offs[m] + j * cols + k] = grads[offs[m] + j * cols + k] + delta[j] * input[k];
            }
        }
        let back: Vec<T> = (0..cols)
            .map(|k| {
                let g = (0..rows).fold(T::zero(), |acc, j| acc + w[offs[m] + j * cols + k] * delta[j]);
                if m == 0 || input[k] > T::zero() {
                    g
                } else {
                    T::zero()
                }
            })
            .collect();
        delta = back;
    }
    delta
}
