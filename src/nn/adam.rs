//! Adam (torch.optim.Adam semantics, fp32 master weights and moments) over a [`ParamStore`], one parameter
//! group at a time. Kernel `adam_step` (`glsl/optim/adam_step.comp`); CPU twin [`crate::reference::adam`].
//!
//! - Bindings: 0 params, 1 grads, 2 m, 3 v — the same chunk of each of the store's four arrays, bound whole;
//!   4 a gate flag ([`step_gated`]: a set flag skips the update on the device; ungated, binding 4 is the params
//!   chunk again and is not read).
//! - Push (44 bytes): `{n, offset, step_size, bc2_sqrt, beta1, one_minus_beta1, beta2, one_minus_beta2, eps,
//!   weight_decay, grad_scale}`; the kernel updates chunk elements `[offset, offset + n)`.
//! - Spec: VEC, elements per invocation, read and written VEC floats at a time: 8 over the 8-aligned body of a
//!   range, 1 over its unaligned head and tail; GATED, 0 or 1.
//! - Threads: one invocation per VEC elements, 64 per group.
//!
//! [`step`] dispatches once per chunk range of each stepped group's element range (groups are contiguous, see
//! [`crate::nn::params`]). Semantics per group g, with `lr = store.lr(g)` (the group's schedule at the schedule
//! step, or at the run progress for a schedule that spans the run):
//! - not in `has_grad` (no gradient this iteration, torch's `p.grad is None`): not stepped at all — no moment
//!   update, its step counter does not advance (nerfacto.md §8.9);
//! - lr 0 (a frozen group): not stepped either (torch would still move the moments; nothing here reads them);
//! - otherwise its step counter t advances and every element gets
//!   `g = grad * grad_scale + weight_decay * p; m = b1 m + (1-b1) g; v = b2 v + (1-b2) g²;
//!    p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)`.
//!
//! The schedule step (nerfstudio's scheduler, shared by all groups) advances once per call, stepped or not.
//! Counters change when the step is recorded: submit the recorder (and keep the store alive) before reading
//! the arrays or saving.

use crate::gpu::{GpuError, GpuResult, Kernel, Recorder};
use crate::nn::params::ParamStore;
use crate::shaders;

/// Adam hyper-parameters of one parameter group.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct AdamHyper {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// L2 weight decay added to the gradient (torch's `weight_decay`).
    pub weight_decay: f64,
}

impl Default for AdamHyper {
    /// nerfacto's values (nerfacto.md §1.1): betas (0.9, 0.999), eps 1e-15, no weight decay.
    fn default() -> Self {
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-15, weight_decay: 0.0 }
    }
}

crate::push_constants! {
    /// `adam_step`'s push constants (see the module documentation).
    #[derive(Debug)]
    pub struct AdamPush {
        n: u32,
        offset: u32,
        step_size: f32,
        bc2_sqrt: f32,
        beta1: f32,
        one_minus_beta1: f32,
        beta2: f32,
        one_minus_beta2: f32,
        eps: f32,
        weight_decay: f32,
        grad_scale: f32,
    }
}

/// Elements one `adam_step` invocation updates where the range allows (read and written 8 floats at a time).
const ADAM_VEC: usize = 8;

/// The `adam_step` pipelines [`step`] uses (8 elements per invocation, and 1), created on first use.
pub fn kernels(ctx: &crate::gpu::Context, gated: bool) -> GpuResult<[Kernel<AdamPush>; 2]> {
    let g = u32::from(gated);
    Ok([
        Kernel::with_spec(ctx, &shaders::ADAM_STEP, &[("VEC", ADAM_VEC as u32), ("GATED", g)])?,
        Kernel::with_spec(ctx, &shaders::ADAM_STEP, &[("VEC", 1), ("GATED", g)])?,
    ])
}

/// What [`step`] did to one group.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct GroupStep {
    /// The learning rate at this schedule step.
    pub lr: f64,
    /// The group's step counter after this call (unchanged when not stepped).
    pub t: u64,
    pub stepped: bool,
}

/// Records one optimiser step over the store. `has_grad[g]` says whether group g received a gradient this
/// iteration; `grad_scale` multiplies every gradient first (1 / loss scale, or 1).
pub fn step(
    rec: &mut Recorder,
    store: &mut ParamStore,
    has_grad: &[bool],
    grad_scale: f32,
) -> GpuResult<Vec<GroupStep>> {
    step_gated(rec, store, has_grad, grad_scale, None)
}

/// [`step`], skipped on the device when `gate[0]` is non-zero at the time the kernels run. The host's counters
/// advance as if it ran: when the gate turns out to have been set, [`ParamStore::undo_step`] with the returned
/// report puts them back.
pub fn step_gated(
    rec: &mut Recorder,
    store: &mut ParamStore,
    has_grad: &[bool],
    grad_scale: f32,
    gate: Option<&crate::gpu::GpuBuffer<u32>>,
) -> GpuResult<Vec<GroupStep>> {
    let n_groups = store.groups().len();
    if has_grad.len() != n_groups {
        return Err(GpuError::Dispatch {
            kernel: "adam_step".into(),
            msg: format!("{} gradient flags for {n_groups} parameter groups", has_grad.len()),
        });
    }
    let [wide, narrow] = kernels(rec.context(), gate.is_some())?;
    let mut report = Vec::with_capacity(n_groups);
    let mut new_steps = store.group_steps().to_vec();
    // Every dispatch updates its own element range: one group without barriers among them.
    rec.independent(|rec| {
        for (g, group) in store.groups().iter().enumerate() {
            let lr = store.lr(g);
            let stepped = has_grad[g] && lr != 0.0;
            if stepped {
                new_steps[g] += 1;
                let t = new_steps[g].min(i32::MAX as u64) as i32;
                let h = &group.adam;
                let mut push = AdamPush {
                    n: 0,
                    offset: 0,
                    step_size: (lr / (1.0 - h.beta1.powi(t))) as f32,
                    bc2_sqrt: (1.0 - h.beta2.powi(t)).sqrt() as f32,
                    beta1: h.beta1 as f32,
                    one_minus_beta1: (1.0 - h.beta1) as f32,
                    beta2: h.beta2 as f32,
                    one_minus_beta2: (1.0 - h.beta2) as f32,
                    eps: h.eps as f32,
                    weight_decay: h.weight_decay as f32,
                    grad_scale,
                };
                for (c, r) in store.layout().chunk_ranges(store.layout().group_range(g)) {
                    let [p, g, m, v] =
                        [store.params(), store.grads(), store.m(), store.v()].map(|a| a.chunks()[c].binding());
                    let gate = gate.map_or_else(|| p.clone(), |f| f.binding());
                    let bindings = [p, g, m, v, gate];
                    // ADAM_VEC elements per invocation over the aligned body, one per invocation elsewhere.
                    let [head, body, tail] = crate::ops::aligned_split(r.start, r.end, ADAM_VEC);
                    for (k, range, per) in [(&narrow, head, 1), (&wide, body, ADAM_VEC), (&narrow, tail, 1)] {
                        if range.is_empty() {
                            continue;
                        }
                        push.n = range.len() as u32;
                        push.offset = range.start as u32;
                        rec.dispatch(k, &bindings, &push, (range.len() / per) as u64)?;
                    }
                }
            }
            report.push(GroupStep { lr, t: new_steps[g], stepped });
        }
        Ok(())
    })?;
    let (steps, schedule) = store.counters_mut();
    steps.copy_from_slice(&new_steps);
    *schedule += 1;
    Ok(report)
}
