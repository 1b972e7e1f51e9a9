//! Camera pose refinement on the GPU (spec/nerfacto.md §2.4): the Rust side of `glsl/pose/*.comp`. Recorded only
//! when the model's camera optimiser is on:
//!
//! - forward, after `ray_gen`: `pose_apply` corrects each training ray with its camera's [t, w];
//! - backward, per sampling level whose density field received gradients: `hashgrid_bwd_input` (dL/dhash input) then
//!   `pose_ray_grad` (through the contraction to the ray's origin and direction, plus the SH view-direction term on
//!   the NeRF level), then `pose_reduce` adds each ray's share to its camera's gradient;
//! - once per step: `pose_regularizer` (0.01 mean |t| + 0.001 mean |w|).
//!
//! The CPU twins are in `crate::reference::pose`.

use super::kernels::{Geometry, RayBuffers};
use crate::gpu::{Context, GpuBuffer, GpuResult, Kernel, LargeArray, Recorder};
use crate::shaders;

crate::push_constants! {
    struct ApplyPush {
        params: u64,
        shift: u32,
        pose_offset: u32,
        n_rays: u32,
        pad: u32,
    }
}

crate::push_constants! {
    struct RayGradPush {
        n_rays: u32,
        n: u32,
        near: f32,
        far: f32,
        contraction: u32,
        accumulate: u32,
        sh: u32,
        dx_stride: u32,
    }
}

crate::push_constants! {
    struct ReducePush {
        params: u64,
        grads: u64,
        shift: u32,
        pose_offset: u32,
        n_rays: u32,
        pad: u32,
    }
}

crate::push_constants! {
    struct RegularizerPush {
        params: u64,
        grads: u64,
        shift: u32,
        pose_offset: u32,
        n_cams: u32,
        inv_n_train: f32,
        trans_weight: f32,
        rot_weight: f32,
    }
}

/// Where the pose corrections live: the store's parameter and gradient arrays and the slot's first float.
#[derive(Copy, Clone)]
pub struct PoseSlot<'a> {
    pub params: &'a LargeArray<f32>,
    pub grads: &'a LargeArray<f32>,
    pub offset: usize,
}

impl PoseSlot<'_> {
    fn deps(&self) -> Vec<ash::vk::Buffer> {
        let mut d = self.params.deps();
        d.extend(self.grads.deps());
        d
    }
}

/// One level's inputs to `pose_ray_grad`.
pub struct LevelGrad<'a> {
    /// Samples per ray.
    pub n: usize,
    pub edges: &'a GpuBuffer<f32>,
    /// dL/dhash input, 3 per sample.
    pub dpos: &'a GpuBuffer<f32>,
    /// The colour MLP's input gradient rows and their stride (NeRF level: adds the view-direction term).
    pub colour_dx: Option<(&'a GpuBuffer<f32>, usize)>,
    /// The SH columns of `colour_dx` that depend on the direction (`field.direction_sh_degree` squared).
    pub sh_count: usize,
    /// Add to the per-ray gradient instead of overwriting it.
    pub accumulate: bool,
}

pub struct PoseKernels {
    apply: Kernel<ApplyPush>,
    /// `pose_ray_grad`, or `pose_ray_grad_lanes` (32 invocations per ray) where [`super::kernels::default_ray_lanes`]
    /// picks them; `ray_lanes` says which.
    ray_grad: Kernel<RayGradPush>,
    ray_lanes: bool,
    reduce: Kernel<ReducePush>,
    regularizer: Kernel<RegularizerPush>,
}

impl PoseKernels {
    pub fn new(ctx: &Context) -> GpuResult<Self> {
        Self::with_ray_lanes(ctx, super::kernels::default_ray_lanes(ctx)?)
    }

    /// As [`PoseKernels::new`], with the per-ray gradient over 32 lanes per ray (`lanes`) or one invocation per ray.
    pub fn with_ray_lanes(ctx: &Context, lanes: bool) -> GpuResult<Self> {
        super::kernels::check_ray_lanes(ctx, lanes)?;
        let ray_grad = if lanes { &shaders::POSE_RAY_GRAD_LANES } else { &shaders::POSE_RAY_GRAD };
        Ok(Self {
            apply: Kernel::new(ctx, &shaders::POSE_APPLY)?,
            ray_grad: Kernel::new(ctx, ray_grad)?,
            ray_lanes: lanes,
            reduce: Kernel::new(ctx, &shaders::POSE_REDUCE)?,
            regularizer: Kernel::new(ctx, &shaders::POSE_REGULARIZER)?,
        })
    }

    /// Corrects the rays in place; the uncorrected directions go to `raw_dirs`.
    pub fn apply(
        &self,
        rec: &mut Recorder,
        slot: PoseSlot,
        cam_idx: &GpuBuffer<u32>,
        rays: RayBuffers,
        raw_dirs: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let push = ApplyPush {
            params: slot.params.table_address()?,
            shift: slot.params.chunk_shift(),
            pose_offset: slot.offset as u32,
            n_rays: rays.n_rays as u32,
            pad: 0,
        };
        let bindings = [cam_idx.binding(), rays.origins.binding(), rays.dirs.binding(), raw_dirs.binding()];
        rec.dispatch_named("pose_apply", &self.apply, &bindings, &slot.params.deps(), &push, rays.n_rays as u64)
    }

    /// Adds (or writes) one level's contribution to each ray's (dL/dorigin, dL/ddirection) in `ray_grads`.
    pub fn ray_grad(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        level: &LevelGrad,
        dummy: &GpuBuffer<f32>,
        ray_grads: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let (cdx, stride) = level.colour_dx.unwrap_or((dummy, 0));
        let push = RayGradPush {
            n_rays: rays.n_rays as u32,
            n: level.n as u32,
            near: geo.near,
            far: geo.far,
            contraction: u32::from(geo.contraction),
            accumulate: u32::from(level.accumulate),
            sh: if level.colour_dx.is_some() { level.sh_count.min(crate::nn::sh::SH_DIM) as u32 } else { 0 },
            dx_stride: stride as u32,
        };
        let bindings = [
            rays.origins.binding(),
            rays.dirs.binding(),
            level.edges.binding(),
            level.dpos.binding(),
            cdx.binding(),
            ray_grads.binding(),
        ];
        let per_ray = if self.ray_lanes { super::kernels::RAY_LANES } else { 1 };
        rec.dispatch(&self.ray_grad, &bindings, &push, (rays.n_rays * per_ray) as u64)
    }

    /// Adds every ray's share to its camera's [t, w] gradient.
    pub fn reduce(
        &self,
        rec: &mut Recorder,
        slot: PoseSlot,
        (ray_grads, raw_dirs, cam_idx): (&GpuBuffer<f32>, &GpuBuffer<f32>, &GpuBuffer<u32>),
        n_rays: usize,
    ) -> GpuResult<()> {
        let push = ReducePush {
            params: slot.params.table_address()?,
            grads: slot.grads.table_address()?,
            shift: slot.params.chunk_shift(),
            pose_offset: slot.offset as u32,
            n_rays: n_rays as u32,
            pad: 0,
        };
        let bindings = [ray_grads.binding(), raw_dirs.binding(), cam_idx.binding()];
        rec.dispatch_named("pose_reduce", &self.reduce, &bindings, &slot.deps(), &push, n_rays as u64)
    }

    /// The regulariser over `n_cams` cameras (mean over `n_train`): per-camera losses and gradients.
    pub fn regularizer(
        &self,
        rec: &mut Recorder,
        slot: PoseSlot,
        (n_cams, n_train): (usize, usize),
        (trans_weight, rot_weight): (f32, f32),
        losses: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let push = RegularizerPush {
            params: slot.params.table_address()?,
            grads: slot.grads.table_address()?,
            shift: slot.params.chunk_shift(),
            pose_offset: slot.offset as u32,
            n_cams: n_cams as u32,
            inv_n_train: 1.0 / n_train.max(1) as f32,
            trans_weight,
            rot_weight,
        };
        rec.dispatch_named(
            "pose_regularizer",
            &self.regularizer,
            &[losses.binding()],
            &slot.deps(),
            &push,
            n_cams as u64,
        )
    }
}
