//! Surface normals from the NeRF density field, as nerfstudio's "predicted normals" without a normal head:
//! n = -grad(sigma) / |grad(sigma)|. sigma = scale * exp(raw) with scale > 0, so grad(sigma) is parallel to
//! grad(raw) and the normal is the normalised -grad(raw).
//!
//! GPU chain per chunk of points (normalised frame), with the field's own kernels: hash input h(x) (CPU, the
//! render kernels' contraction) -> `hashgrid_fwd` -> density MLP `mlp_fwd` (training variant, activations kept)
//! -> `mlp_bwd` with dL/draw = 1 on the density output and 0 on the geometric features -> dL/dencoding ->
//! `hashgrid_bwd_input` -> dL/dh; then, on the CPU, the contraction's Jacobian
//! ([`crate::maths::field::hash_input_grad`], the maths of `hash_input_grad` in glsl/pose/pose_common.glsl) gives
//! dL/dx. The MLP backward also adds weight gradients to the store's gradient array; they are zeroed afterwards, so
//! the store is left as it was found.

use super::model::Model;
use crate::gpu::{BufferDesc, Context, GpuBuffer, GpuResult, MemoryCategory};
use crate::maths::field::hash_input;
use crate::maths::field::hash_input_grad;
use crate::nn::mlp::MlpTrainBuffers;
use crate::nn::{ParamSlice, RowSlice};

/// Points per submission.
pub const NORMAL_CHUNK: usize = 16384;

/// d(raw density)/dx of the NeRF field at `points` (normalised frame), one gradient per point.
pub fn density_gradients(ctx: &Context, model: &Model, points: &[[f64; 3]]) -> GpuResult<Vec<[f64; 3]>> {
    let f = &model.field;
    let c = &f.mlp.config;
    let contraction = model.cfg.sampling.scene_contraction;
    let n_max = NORMAL_CHUNK.min(points.len()).max(1);
    let buf = |name: &str, len: usize| {
        GpuBuffer::<f32>::new(ctx, &BufferDesc { name, len: len.max(1), category: MemoryCategory::Activations })
    };
    let positions = buf("normals positions", 3 * n_max)?;
    let enc = buf("normals encoding", n_max * c.in_pad())?;
    let raw = buf("normals density", n_max * c.n_output)?;
    let dy = buf("normals dL/draw", n_max * c.n_output)?;
    let dx = buf("normals dL/dencoding", n_max * c.in_pad())?;
    let dpos = buf("normals dL/dh", 3 * n_max)?;
    let acts = buf("normals activations", c.hidden_floats(n_max))?;
    let deltas = buf("normals deltas", c.delta_floats(n_max))?;
    let scratch = buf("normals wgrad scratch", c.wgrad_scratch_floats(n_max))?;
    let store = &model.store;
    let grid_p = ParamSlice { array: store.params(), offset: f.grid_offset };
    let mlp_p = ParamSlice { array: store.params(), offset: f.mlp_offset };
    let mlp_g = ParamSlice { array: store.grads(), offset: f.mlp_offset };
    let mut seed = vec![0.0f32; n_max * c.n_output];
    seed.iter_mut().step_by(c.n_output).for_each(|v| *v = 1.0);
    ctx.upload(&dy, 0, &seed)?;
    let mut out = Vec::with_capacity(points.len());
    for chunk in points.chunks(n_max) {
        let n = chunk.len();
        let xs: Vec<[f32; 3]> = chunk.iter().map(|p| p.map(|v| v as f32)).collect();
        let h: Vec<f32> = xs.iter().flat_map(|&x| hash_input(x, contraction).0).collect();
        ctx.upload(&positions, 0, &h)?;
        let mut rec = ctx.recorder("density normals")?;
        f.grid.forward(&mut rec, grid_p, &positions, n, &enc, f.enc_slot)?;
        let input = RowSlice { buf: &enc, stride: c.in_pad(), col: 0 };
        let output = RowSlice { buf: &raw, stride: c.n_output, col: 0 };
        f.mlp.forward(&mut rec, mlp_p, input, n, output, &acts)?;
        let bufs = MlpTrainBuffers { acts: &acts, deltas: &deltas, scratch: &scratch };
        let dys = RowSlice { buf: &dy, stride: c.n_output, col: 0 };
        let dxs = RowSlice { buf: &dx, stride: c.in_pad(), col: 0 };
        f.mlp.backward(&mut rec, mlp_p, mlp_g, (input, output, dys), n, &bufs, Some(dxs))?;
        f.grid.backward_input(&mut rec, grid_p, &positions, n, dxs, &dpos)?;
        rec.submit_and_wait()?;
        let dh = ctx.download_range(&dpos, 0, 3 * n)?;
        for (x, g) in xs.iter().zip(dh.chunks(3)) {
            let gx = hash_input_grad(x.map(f64::from), [0, 1, 2].map(|k| g[k] as f64), contraction);
            out.push(gx);
        }
    }
    let mut rec = ctx.recorder("zero gradients after normals")?;
    store.zero_grads(&mut rec)?;
    rec.submit_and_wait()?;
    Ok(out)
}

/// The outward normal -g/|g| of a density gradient, turned to face `view_dir` (the ray that saw the point:
/// dot(view_dir, n) <= 0, nerfstudio's `reorient_normals`); `None` where the gradient vanishes.
pub fn normal_from_gradient(g: [f64; 3], view_dir: [f64; 3]) -> Option<[f64; 3]> {
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    let n = g.map(|v| -v / len);
    let facing = n[0] * view_dir[0] + n[1] * view_dir[1] + n[2] * view_dir[2];
    Some(if facing > 0.0 { n.map(|v| -v) } else { n })
}
