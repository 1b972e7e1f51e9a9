//! The VRAM plan: every device buffer the trainer allocates, from the same code that allocates them.
//!
//! - Parameter store: [`ParamLayout`] from [`ModelShapes::store_desc`] (what `Model::new` builds), split into
//!   chunks by [`chunk_lens`] (what `LargeArray` creates), four arrays (parameters, gradients, Adam m and v),
//!   each with a chunk table when the device has bufferDeviceAddress.
//! - One level table per hash grid ([`HashGridConfig::levels`], uploaded by `HashGrid::new`).
//! - The camera table (one [`GpuCamera`] per dataset frame, and per band of each frame with `rig_cameras`, uploaded
//!   by `Pipeline::new`).
//! - The training chunk and the evaluation chunk: [`ChunkBuffers::with_shapes`] run with [`PlanAlloc`].
//! - The two staging buffers at the size of the largest upload and readback the trainer makes
//!   ([`staging_bytes`]): parameter pieces of [`PIECE`] elements at initialisation, checkpoint and resume,
//!   level/chunk/camera tables, the evaluation chunks' rays and outputs (a training step moves its rays through its own host
//!   buffers, below).
//! - The NaN/Inf guard's flags ([`crate::nerf::guard::Guard::word_count`] u32 words) and, per step in flight
//!   (`trainer.steps_in_flight`), the step's host input and output buffers ([`StepLayout`]), allocated with the
//!   first training step.
//!
//! The total is the persistent buffers plus the largest transient set: an upper bound of the ledger's peak
//! (the peak reaches it once a checkpoint has been written and a step follows, as in any run longer than
//! `steps_per_save`).

use super::device::{DeviceRule, DeviceRuleInfo};
use super::error::PlanError;
use crate::gpu::large_array::chunk_lens;
use crate::gpu::staging::staging_bytes;
use crate::gpu::MemoryCategory;
use crate::nerf::buffers::{ChunkBuffers, PlanAlloc, RAY_OUT_FIXED};
use crate::nerf::model::ModelShapes;
use crate::nerf::rays::GpuCamera;
use crate::nerf::step_io::StepLayout;
use crate::nn::hashgrid::{HashGridConfig, HashLevel};
use crate::nn::params::{ParamLayout, PIECE};
use serde::Serialize;

/// Which part of the trainer a buffer belongs to.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Part {
    ParameterStore,
    LevelTables,
    CameraTable,
    TrainChunk,
    EvalChunk,
    Staging,
    /// Alive only during the NaN guard's reduction.
    NanGuard,
}

impl Part {
    pub fn name(self) -> &'static str {
        match self {
            Part::ParameterStore => "parameter store",
            Part::LevelTables => "hash-grid level tables",
            Part::CameraTable => "camera table",
            Part::TrainChunk => "training chunk",
            Part::EvalChunk => "evaluation chunk",
            Part::Staging => "staging",
            Part::NanGuard => "NaN/Inf guard flags",
        }
    }
}

/// One planned buffer: its requested size and the bytes the device reserves for it.
#[derive(Clone, Debug, Serialize)]
pub struct VramEntry {
    pub name: String,
    pub category: MemoryCategory,
    pub part: Part,
    pub size: u64,
    pub bytes: u64,
    pub transient: bool,
}

/// Ray counts the plan is made for.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub struct RayCounts {
    pub rays_per_batch: usize,
    pub rays_per_chunk: usize,
    pub eval_rays_per_chunk: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct CategoryTotal {
    pub category: MemoryCategory,
    pub bytes: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct VramPlan {
    pub model: String,
    pub bands: usize,
    pub n_cameras: usize,
    pub rays: RayCounts,
    pub device: DeviceRuleInfo,
    pub n_params: usize,
    pub entries: Vec<VramEntry>,
    /// Per category: persistent bytes plus the category's share of the largest transient set.
    pub categories: Vec<CategoryTotal>,
    pub persistent_bytes: u64,
    pub transient_bytes: u64,
    /// Persistent + transient: the planned peak.
    pub total_bytes: u64,
    /// Buffers a device cannot hold (one binding or one allocation too large).
    pub problems: Vec<String>,
}

/// Bytes of the upload and readback staging buffers for the given transfers.
fn staging(max_upload: u64, max_readback: u64) -> (u64, u64) {
    (staging_bytes(max_upload), staging_bytes(max_readback))
}

/// Plans the trainer's device memory for `shapes` (model, bands, cameras) at `rays` on `dev`.
pub fn plan_vram(shapes: &ModelShapes, rays: &RayCounts, dev: &DeviceRule) -> Result<VramPlan, PlanError> {
    let mut entries: Vec<VramEntry> = Vec::new();
    let mut push = |name: String, category, part, size: u64, transient| {
        entries.push(VramEntry { name, category, part, size, bytes: dev.bytes(size), transient });
    };
    let (f32s, u64s) = (4u64, 8u64);
    let bands = shapes.bands as u64;

    // Parameter store.
    let shift = dev.param_chunk_shift();
    let layout = ParamLayout::new(&shapes.param_groups(), &shapes.param_slots(), shift)
        .map_err(|e| PlanError::Layout(e.to_string()))?;
    let chunks = chunk_lens(layout.len(), shift);
    let name = &shapes.cfg.name;
    for (what, cat) in [
        ("params", MemoryCategory::Parameters),
        ("grads", MemoryCategory::Gradients),
        ("adam m", MemoryCategory::OptimizerState),
        ("adam v", MemoryCategory::OptimizerState),
    ] {
        for (c, &len) in chunks.iter().enumerate() {
            push(format!("{name} {what}[chunk {c}]"), cat, Part::ParameterStore, len as u64 * f32s, false);
        }
        if dev.buffer_device_address {
            push(format!("{name} {what}[chunk table]"), cat, Part::ParameterStore, chunks.len() as u64 * u64s, false);
        }
    }
    // Hash-grid level tables and the camera table.
    let grids: Vec<&HashGridConfig> = shapes.grids();
    let level_bytes = |g: &HashGridConfig| (g.levels().len() * std::mem::size_of::<HashLevel>()) as u64;
    for g in &grids {
        push("hash grid levels".into(), MemoryCategory::Other, Part::LevelTables, level_bytes(g), false);
    }
    let camera_bytes = (shapes.table_cameras * std::mem::size_of::<GpuCamera>()) as u64;
    push("camera table".into(), MemoryCategory::Rays, Part::CameraTable, camera_bytes, false);

    // Training and evaluation chunks (the trainer's own allocation code, recording instead of allocating).
    for (r, train, part) in
        [(rays.rays_per_chunk, true, Part::TrainChunk), (rays.eval_rays_per_chunk, false, Part::EvalChunk)]
    {
        let mut a = PlanAlloc::default();
        ChunkBuffers::with_shapes(&mut a, shapes, r, train).map_err(|e| PlanError::Layout(e.to_string()))?;
        for b in a.buffers {
            push(b.name, b.category, part, b.bytes, false);
        }
    }

    // Staging: the largest upload and readback.
    let piece = layout.slots().iter().map(|s| PIECE.min(s.len).min(1usize << shift) as u64 * f32s).max().unwrap_or(0);
    let per_chunk_up = |r: usize| (r as u64 * 3 * 4).max(r as u64 * (bands + 1) * f32s);
    let per_chunk_down = |r: usize| r as u64 * (RAY_OUT_FIXED as u64 + bands) * f32s;
    let max_up = [
        piece,
        camera_bytes,
        chunks.len() as u64 * u64s,
        grids.iter().map(|g| level_bytes(g)).max().unwrap_or(0),
        per_chunk_up(rays.eval_rays_per_chunk),
        bands * f32s,
    ]
    .into_iter()
    .max()
    .unwrap_or(0);
    let max_down = [piece, per_chunk_down(rays.eval_rays_per_chunk), f32s].into_iter().max().unwrap_or(0);
    let (up, down) = staging(max_up, max_down);
    push("staging upload".into(), MemoryCategory::Staging, Part::Staging, up, false);
    push("staging readback".into(), MemoryCategory::Staging, Part::Staging, down, false);

    // The NaN/Inf guard's flags (check_finite needs no scratch), and each step in flight's host buffers.
    let n_props = shapes.cfg.proposals.len();
    let words = crate::nerf::guard::Guard::word_count(n_props, chunks.len());
    push("NaN guard flags".into(), MemoryCategory::Other, Part::NanGuard, words as u64 * 4, false);
    let step = StepLayout::new(rays.rays_per_batch, shapes.bands, n_props, words, shapes.n_cameras);
    for _ in 0..shapes.cfg.trainer.steps_in_flight.clamp(1, 3) {
        push("step inputs".into(), MemoryCategory::Staging, Part::Staging, step.input_bytes, false);
        push("step outputs".into(), MemoryCategory::Staging, Part::Staging, step.output_bytes, false);
    }

    let persistent_bytes: u64 = entries.iter().filter(|e| !e.transient).map(|e| e.bytes).sum();
    let transient_bytes: u64 = entries.iter().filter(|e| e.transient).map(|e| e.bytes).sum();
    let categories = MemoryCategory::ALL
        .iter()
        .map(|&c| CategoryTotal {
            category: c,
            bytes: entries.iter().filter(|e| e.category == c).map(|e| e.bytes).sum(),
        })
        .filter(|c| c.bytes > 0)
        .collect();
    let mut problems = Vec::new();
    for e in entries.iter().filter(|e| e.part != Part::Staging) {
        if e.size > dev.max_storage_buffer_range || e.size > dev.max_memory_allocation_size {
            problems.push(format!(
                "{} ({:.1} MiB) is larger than one binding or allocation of this device ({:.0} MiB)",
                e.name,
                e.size as f64 / MIB,
                dev.max_storage_buffer_range.min(dev.max_memory_allocation_size) as f64 / MIB
            ));
        }
    }
    Ok(VramPlan {
        model: name.clone(),
        bands: shapes.bands,
        n_cameras: shapes.n_cameras,
        rays: *rays,
        device: dev.info(),
        n_params: layout.slots().iter().map(|s| s.len).sum(),
        entries,
        categories,
        persistent_bytes,
        transient_bytes,
        total_bytes: persistent_bytes + transient_bytes,
        problems,
    })
}

pub(crate) const MIB: f64 = (1u64 << 20) as f64;

impl VramPlan {
    /// Bytes of one part (persistent and transient).
    pub fn part_bytes(&self, part: Part) -> u64 {
        self.entries.iter().filter(|e| e.part == part).map(|e| e.bytes).sum()
    }

    pub fn fits(&self, budget_bytes: u64) -> bool {
        self.problems.is_empty() && self.total_bytes <= budget_bytes
    }
}
