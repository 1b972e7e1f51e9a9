//! Profile-driven training (`msnerf train --hardware H|auto`): the model's ray counts from the profile (auto:
//! the largest chunks that fit this device), then a plan on this device with the dataset's shape; training is
//! refused before anything is allocated when it does not fit, naming the largest chunk that would.

use super::device::DeviceRule;
use super::error::PlanError;
use super::fit::{fit_chunks, plan, profile_rays, Plan, PlanRequest};
use super::hardware::{HardwareProfile, TrainerProfile};
use super::host::DatasetShape;
use super::vram::RayCounts;
use crate::gpu::Context;
use crate::nerf::config::chunk_within_batch;
use crate::nerf::config::ModelConfig;
use crate::nerf::model::ModelShapes;

/// Resolves `--hardware` (a profile name or file, or `auto`) for training `model` on `ctx`.
pub fn resolve_profile(
    ctx: &Context,
    hardware: &str,
    model: &ModelConfig,
    data: &DatasetShape,
) -> Result<HardwareProfile, PlanError> {
    if hardware != "auto" {
        return HardwareProfile::resolve(hardware);
    }
    let t = &model.trainer;
    let mut p = HardwareProfile::auto(
        ctx,
        TrainerProfile {
            rays_per_batch: t.rays_per_batch,
            rays_per_chunk: chunk_within_batch(t.rays_per_chunk, t.rays_per_batch),
            eval_rays_per_chunk: t.eval_rays_per_chunk,
        },
    );
    // Fit the chunks to this device: the model's sizes, or smaller where they do not fit.
    let mut shapes = ModelShapes::new(model, data.bands, data.n_frames);
    shapes.table_cameras = data.table_cameras();
    let dev = DeviceRule::from_context(ctx);
    let rays = profile_rays(&p);
    let f = fit_chunks(
        &shapes,
        &RayCounts { eval_rays_per_chunk: super::fit::FIT_STEP, ..rays },
        &dev,
        p.vram_budget_bytes(),
    )?;
    if let Some(r) = f.max_rays_per_chunk {
        p.trainer.rays_per_chunk = rays.rays_per_chunk.min(r);
        let f2 = fit_chunks(
            &shapes,
            &RayCounts { rays_per_chunk: p.trainer.rays_per_chunk, ..rays },
            &dev,
            p.vram_budget_bytes(),
        )?;
        if let Some(e) = f2.max_eval_rays_per_chunk {
            p.trainer.eval_rays_per_chunk = rays.eval_rays_per_chunk.min(e);
        }
    }
    Ok(p)
}

/// Sets the model's ray counts from the profile.
pub fn apply_profile(model: &mut ModelConfig, p: &HardwareProfile) {
    let r = profile_rays(p);
    model.trainer.rays_per_batch = r.rays_per_batch;
    model.trainer.rays_per_chunk = r.rays_per_chunk;
    model.trainer.eval_rays_per_chunk = r.eval_rays_per_chunk;
}

/// Plans training `model` (its ray counts as they are) on `ctx` against `p`'s budgets; an error, before anything
/// is allocated, when it does not fit.
pub fn check_training(
    ctx: &Context,
    model: &ModelConfig,
    p: &HardwareProfile,
    data: DatasetShape,
) -> Result<Plan, PlanError> {
    let t = &model.trainer;
    let rays = RayCounts {
        rays_per_batch: t.rays_per_batch,
        rays_per_chunk: t.rays_per_chunk,
        eval_rays_per_chunk: t.eval_rays_per_chunk,
    };
    let dev = DeviceRule::from_context(ctx);
    let req = PlanRequest { model, profile: p, data, rays: Some(rays), fit: false };
    let mut pl = plan(&req, &dev)?;
    if pl.fits {
        return Ok(pl);
    }
    let mut shapes = ModelShapes::new(model, pl.data.bands, pl.data.n_frames);
    shapes.table_cameras = pl.data.table_cameras();
    let f = fit_chunks(&shapes, &rays, &dev, p.vram_budget_bytes())?;
    let hint = match (pl.fits_vram, f.max_rays_per_chunk) {
        (true, _) => String::new(),
        (false, Some(r)) => format!(
            "; the largest training chunk that fits is --rays-per-chunk {r} (the batch of {} rays is then processed in {} passes)",
            t.rays_per_batch,
            t.rays_per_batch.div_ceil(r)
        ),
        (false, None) => format!(
            "; no training chunk fits with an evaluation chunk of {} rays (try a smaller eval_rays_per_chunk)",
            t.eval_rays_per_chunk
        ),
    };
    pl.fit = Some(f);
    Err(PlanError::DoesNotFit { profile: p.name.clone(), problems: pl.problems().join("; "), hint })
}

/// What profile-driven training settles on: the model with the profile's ray counts (and the caller's overrides),
/// the plan that fits, and the cache settings it implies.
#[derive(Debug, Clone)]
pub struct FittedTraining {
    pub model: ModelConfig,
    pub plan: Plan,
    pub host_budget_bytes: u64,
    /// Resampling interval M when not every image fits (None: all resident).
    pub resample_every: Option<u64>,
}

impl FittedTraining {
    /// One line for the command's output.
    pub fn describe(&self) -> String {
        let t = &self.model.trainer;
        let p = &self.plan;
        format!(
            "hardware {}: {} rays per batch in chunks of {}, eval chunks of {}; planned VRAM {:.2} of {:.2} GiB; cache N \
             = {} of {} images{}",
            p.profile,
            t.rays_per_batch,
            t.rays_per_chunk,
            t.eval_rays_per_chunk,
            p.vram.total_bytes as f64 / (1u64 << 30) as f64,
            p.vram_budget_bytes as f64 / (1u64 << 30) as f64,
            p.host.n_resident,
            p.host.n_images,
            p.host.resample_every.map(|m| format!(", M = {m}")).unwrap_or_default()
        )
    }
}

/// Fits `model` to `hardware` (a profile name or file, or `auto`) for training on `ds` on `ctx`: the profile's ray
/// counts, then `overrides` (explicit flags win over the profile), then the plan, refused before anything is
/// allocated when it does not fit.
pub fn fit_training(
    ctx: &Context,
    hardware: &str,
    model: ModelConfig,
    ds: &crate::data::Dataset,
    overrides: impl FnOnce(ModelConfig) -> Result<ModelConfig, PlanError>,
) -> Result<FittedTraining, PlanError> {
    let shape = DatasetShape::from_dataset(ds);
    let profile = resolve_profile(ctx, hardware, &model, &shape)?;
    let mut m = model;
    apply_profile(&mut m, &profile);
    let m = overrides(m)?;
    let plan = check_training(ctx, &m, &profile, shape)?;
    Ok(FittedTraining {
        host_budget_bytes: plan.host.cache_budget_bytes,
        resample_every: plan.host.resample_every,
        model: m,
        plan,
    })
}
