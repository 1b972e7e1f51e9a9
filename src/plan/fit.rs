//! The whole plan for one (model, hardware profile, dataset): VRAM against the profile's budget, host memory
//! against its host budget, and the largest training and evaluation chunks that fit.

use super::device::DeviceRule;
use super::error::PlanError;
use super::hardware::HardwareProfile;
use super::host::{plan_host, DatasetShape, HostPlan};
use super::vram::{plan_vram, RayCounts, VramPlan};
use crate::nerf::config::chunk_within_batch;
use crate::nerf::config::ModelConfig;
use crate::nerf::model::ModelShapes;
use serde::Serialize;

/// Chunk sizes the fit tries are multiples of this (the paper's advice: multiples of 128 rays).
pub const FIT_STEP: usize = 128;
/// The largest chunk the fit tries.
pub const FIT_MAX: usize = 1 << 20;

/// What to plan.
pub struct PlanRequest<'a> {
    pub model: &'a ModelConfig,
    pub profile: &'a HardwareProfile,
    pub data: DatasetShape,
    /// Ray counts; None: the profile's.
    pub rays: Option<RayCounts>,
    /// Also search the largest chunks that fit.
    pub fit: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct FitResult {
    /// Largest training `rays_per_chunk` (a multiple of [`FIT_STEP`]) that fits with the planned eval chunk.
    pub max_rays_per_chunk: Option<usize>,
    /// Largest `eval_rays_per_chunk` that fits with the planned training chunk.
    pub max_eval_rays_per_chunk: Option<usize>,
    /// The plan at (max_rays_per_chunk, planned eval chunk), when there is one.
    pub total_bytes_at_max: Option<u64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Plan {
    pub profile: String,
    pub data: DatasetShape,
    pub vram_budget_bytes: u64,
    pub vram: VramPlan,
    pub host: HostPlan,
    pub fits_vram: bool,
    pub fits: bool,
    pub fit: Option<FitResult>,
}

impl Plan {
    /// The training process's planned peak host memory: the image cache's peak, the process's own
    /// ([`super::host::PROCESS_OVERHEAD_BYTES`]), and the GPU buffers when the device's memory is host memory (a CPU
    /// device such as lavapipe). What a stage's measured peak is compared with.
    pub fn process_host_bytes(&self, device_memory_is_host: bool) -> u64 {
        self.host.peak_bytes
            + super::host::PROCESS_OVERHEAD_BYTES
            + if device_memory_is_host { self.vram.total_bytes } else { 0 }
    }

    /// Why the plan does not fit, one line per reason (empty when it fits).
    pub fn problems(&self) -> Vec<String> {
        let mut out = self.vram.problems.clone();
        if self.vram.total_bytes > self.vram_budget_bytes {
            out.push(format!(
                "VRAM: the plan needs {:.2} GiB, the budget of {} is {:.2} GiB",
                self.vram.total_bytes as f64 / GIB,
                self.profile,
                self.vram_budget_bytes as f64 / GIB
            ));
        }
        out.extend(self.host.problems.iter().map(|p| format!("host memory: {p}")));
        out
    }
}

const GIB: f64 = (1u64 << 30) as f64;

/// The profile's ray counts, the chunk no larger than the batch (as the trainer's overrides do).
pub fn profile_rays(p: &HardwareProfile) -> RayCounts {
    let t = &p.trainer;
    RayCounts {
        rays_per_batch: t.rays_per_batch,
        rays_per_chunk: chunk_within_batch(t.rays_per_chunk, t.rays_per_batch),
        eval_rays_per_chunk: t.eval_rays_per_chunk,
    }
}

/// Largest multiple of `step` in [step, max] for which `fits` holds (`fits` must be monotone), or None.
pub fn largest_fitting(
    step: usize,
    max: usize,
    mut fits: impl FnMut(usize) -> Result<bool, PlanError>,
) -> Result<Option<usize>, PlanError> {
    if !fits(step)? {
        return Ok(None);
    }
    // fits(lo * step) holds; nothing above hi * step is tried.
    let (mut lo, mut hi) = (1usize, max / step);
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if fits(mid * step)? {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    Ok(Some(lo * step))
}

/// Largest training and evaluation chunks that fit `budget`.
pub fn fit_chunks(
    shapes: &ModelShapes,
    rays: &RayCounts,
    dev: &DeviceRule,
    budget: u64,
) -> Result<FitResult, PlanError> {
    let train = largest_fitting(FIT_STEP, FIT_MAX, |r| {
        Ok(plan_vram(shapes, &RayCounts { rays_per_chunk: r, ..*rays }, dev)?.fits(budget))
    })?;
    let eval = largest_fitting(FIT_STEP, FIT_MAX, |r| {
        Ok(plan_vram(shapes, &RayCounts { eval_rays_per_chunk: r, ..*rays }, dev)?.fits(budget))
    })?;
    let total_bytes_at_max = match train {
        Some(r) => Some(plan_vram(shapes, &RayCounts { rays_per_chunk: r, ..*rays }, dev)?.total_bytes),
        None => None,
    };
    Ok(FitResult { max_rays_per_chunk: train, max_eval_rays_per_chunk: eval, total_bytes_at_max })
}

/// Plans VRAM and host memory for `req` on `dev`.
pub fn plan(req: &PlanRequest, dev: &DeviceRule) -> Result<Plan, PlanError> {
    let p = req.profile;
    let mut shapes = ModelShapes::new(req.model, req.data.bands, req.data.n_frames);
    shapes.table_cameras = req.data.table_cameras();
    let rays = req.rays.unwrap_or_else(|| profile_rays(p));
    let vram = plan_vram(&shapes, &rays, dev)?;
    let budget = p.vram_budget_bytes();
    let host = plan_host(&p.host, p.host_budget_bytes(), &req.data);
    let fit = if req.fit { Some(fit_chunks(&shapes, &rays, dev, budget)?) } else { None };
    let fits_vram = vram.fits(budget);
    let fits = fits_vram && host.fits();
    Ok(Plan {
        profile: p.name.clone(),
        data: req.data.clone(),
        vram_budget_bytes: budget,
        vram,
        host,
        fits_vram,
        fits,
        fit,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn largest_fitting_finds_the_boundary() {
        let f = |limit: usize| largest_fitting(128, 1 << 20, |r| Ok(r <= limit)).unwrap();
        assert_eq!(f(100), None);
        assert_eq!(f(128), Some(128));
        assert_eq!(f(5000), Some(4992));
        assert_eq!(f(usize::MAX), Some(1 << 20));
    }
}
