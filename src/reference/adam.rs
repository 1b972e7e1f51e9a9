//! CPU twin of `glsl/optim/adam_step.comp`: one torch-style Adam step on a range of parameters. The f32
//! instantiation follows the kernel's order of operations; the f64 one is the accurate reference.
//! Scalars that depend only on the step (bias corrections, 1 - beta) are computed in f64 as the host does.

pub use crate::nn::adam::AdamHyper;

use super::real::Real;

/// The per-dispatch scalars of one step (what the kernel receives as push constants), in type `T`.
#[derive(Copy, Clone, Debug)]
pub struct AdamScalars<T> {
    pub step_size: T,
    pub bc2_sqrt: T,
    pub beta1: T,
    pub one_minus_beta1: T,
    pub beta2: T,
    pub one_minus_beta2: T,
    pub eps: T,
    pub weight_decay: T,
    pub grad_scale: T,
}

impl<T: Real> AdamScalars<T> {
    /// Scalars of step `t` (1-based: the group's step counter after this step) at learning rate `lr`.
    pub fn new(h: &AdamHyper, lr: f64, t: u64, grad_scale: f64) -> Self {
        let t = t.min(i32::MAX as u64) as i32;
        let bc1 = 1.0 - h.beta1.powi(t);
        let bc2 = 1.0 - h.beta2.powi(t);
        Self {
            step_size: T::c(lr / bc1),
            bc2_sqrt: T::c(bc2.sqrt()),
            beta1: T::c(h.beta1),
            one_minus_beta1: T::c(1.0 - h.beta1),
            beta2: T::c(h.beta2),
            one_minus_beta2: T::c(1.0 - h.beta2),
            eps: T::c(h.eps),
            weight_decay: T::c(h.weight_decay),
            grad_scale: T::c(grad_scale),
        }
    }
}

/// One Adam step on every element of the slices (all the same length).
pub fn adam_step<T: Real>(params: &mut [T], grads: &[T], m: &mut [T], v: &mut [T], s: &AdamScalars<T>) {
    assert!(grads.len() == params.len() && m.len() == params.len() && v.len() == params.len());
    for j in 0..params.len() {
        let p = params[j];
        let g = grads[j] * s.grad_scale + s.weight_decay * p;
        let mj = s.beta1 * m[j] + s.one_minus_beta1 * g;
        let vj = s.beta2 * v[j] + s.one_minus_beta2 * (g * g);
        m[j] = mj;
        v[j] = vj;
        params[j] = p - s.step_size * (mj / (vj.sqrt() / s.bc2_sqrt + s.eps));
    }
}
