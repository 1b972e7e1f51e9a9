//! `ParamStore`: every trainable value of one model in four [`LargeArray<f32>`]s of equal length — parameters
//! (category `Parameters`), gradients (`Gradients`), and Adam's first and second moments (`OptimizerState`) —
//! laid out in named slots, grouped into optimiser parameter groups with their own learning-rate schedules
//! and step counters, initialised deterministically from a seed, and saved and loaded atomically.
//!
//! # Layout guarantees (kernels rely on them)
//! - Every slot offset is a multiple of [`SLOT_ALIGN`] elements (256 bytes, the largest
//!   `minStorageBufferOffsetAlignment` Vulkan allows), so any slot that lies in one chunk can be bound as a
//!   slice of that chunk ([`ParamStore::slot_binding`]).
//! - **No slot crosses a chunk boundary** unless it is longer than a chunk: a slot of at most 2^shift
//!   elements lies inside one chunk; a longer slot starts on a chunk boundary (chunk index `offset >> shift`,
//!   local offset 0) and fills whole chunks except the last one.
//! - The slots of a group are consecutive (groups in declaration order, slots in declaration order within
//!   a group), so a group is one element range ([`ParamLayout::group_range`]); the padding between slots
//!   holds zeros in all four arrays and stays zero under Adam.
//!
//! Saving and loading: [`ParamStore::save`] and [`ParamStore::load`] (format in `params/file.rs`).

mod file;

pub use file::Checksum;

use super::SettingError;
use crate::gpu::{Binding, Context, GpuError, GpuResult, LargeArray, MemoryCategory, Recorder};
use crate::nn::adam::AdamHyper;
use crate::ops;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::ops::Range;
use std::path::PathBuf;

/// Slot offsets are multiples of this many elements (256 bytes).
pub const SLOT_ALIGN: usize = 64;
/// Scale of the hash-table initialisation U(-1e-4, 1e-4) (tcnn, nerfacto.md §3.4).
pub const HASH_INIT_SCALE: f32 = 1e-4;
/// Elements generated or transferred per piece (bounds host memory for 256 MiB tables).
pub const PIECE: usize = 1 << 22;
const MAX_NAME_BYTES: usize = 1024;

#[derive(Debug, thiserror::Error)]
pub enum ParamError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("parameter layout: {0}")]
    Layout(String),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a valid parameter file: {msg}")]
    Format { path: PathBuf, msg: String },
    #[error("{path}: does not match this model: slot {slot:?}: {msg}")]
    LayoutMismatch { path: PathBuf, slot: String, msg: String },
}

/// One optimiser parameter group: Adam hyper-parameters and an ExponentialDecay learning-rate schedule.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamGroup {
    pub name: String,
    /// Initial learning rate; 0 freezes the group (Adam does not touch it at all).
    pub lr0: f64,
    pub lr_final: f64,
    pub max_steps: u64,
    pub adam: AdamHyper,
    /// The schedule spans the whole run (`optimizer.schedule: run`): when the store has a run progress
    /// ([`ParamStore::set_run_progress`]) the learning rate is evaluated at that fraction instead of
    /// `schedule_step / max_steps`.
    pub over_run: bool,
}

impl ParamGroup {
    /// A group with nerfacto's Adam settings (betas 0.9/0.999, eps 1e-15, no weight decay).
    pub fn new(name: &str, lr0: f64, lr_final: f64, max_steps: u64) -> Self {
        Self { name: name.to_owned(), lr0, lr_final, max_steps, adam: AdamHyper::default(), over_run: false }
    }

    /// nerfstudio's ExponentialDecay without warm-up (nerfacto.md §1.1) after `schedule_step` scheduler steps:
    /// lr = exp((1 - τ) ln lr0 + τ ln lr_final), τ = clip(step / max_steps, 0, 1); `max_steps` 0 means τ = 1.
    pub fn lr_at(&self, schedule_step: u64) -> f64 {
        let tau = if self.max_steps == 0 { 1.0 } else { (schedule_step as f64 / self.max_steps as f64).min(1.0) };
        self.lr_at_progress(tau)
    }

    /// The same schedule at a fraction `tau` of its length (clamped to [0, 1]; NaN counts as 0).
    pub fn lr_at_progress(&self, tau: f64) -> f64 {
        if self.lr0 == 0.0 {
            return 0.0;
        }
        let tau = if tau.is_nan() { 0.0 } else { tau.clamp(0.0, 1.0) };
        match tau {
            // The end points exactly (exp(ln x) is not always x).
            0.0 => self.lr0,
            1.0 => self.lr_final,
            _ => ((1.0 - tau) * self.lr0.ln() + tau * self.lr_final.ln()).exp(),
        }
    }

    fn validate(&self) -> Result<(), SettingError> {
        let h = &self.adam;
        let key = || format!("group {:?}", self.name);
        let ok_lr = self.lr0 == 0.0 || (self.lr0 > 0.0 && self.lr_final > 0.0);
        if !(self.lr0.is_finite() && self.lr_final.is_finite() && ok_lr) {
            return Err(SettingError::new(key(), "learning rates must be finite, lr0 >= 0 and lr_final > 0"));
        }
        let beta_ok = |b: f64| (0.0..1.0).contains(&b);
        if !(beta_ok(h.beta1) && beta_ok(h.beta2) && h.eps > 0.0 && h.weight_decay >= 0.0) {
            return Err(SettingError::new(key(), format!("bad Adam hyper-parameters {h:?}")));
        }
        Ok(())
    }
}

/// One matrix of an MLP slot: `fan_in * fan_out` consecutive elements (their order is the MLP's business).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct MatrixShape {
    pub fan_in: usize,
    pub fan_out: usize,
}

/// What a slot holds, which fixes its length and its initialisation.
#[derive(Clone, Debug, PartialEq)]
pub enum SlotKind {
    /// Hash-grid tables: U(-1e-4, 1e-4).
    HashTable { len: usize },
    /// MLP weight matrices, consecutive: each Xavier-uniform U(±sqrt(6 / (fan_in + fan_out))).
    Mlp { matrices: Vec<MatrixShape> },
    /// An embedding table (e.g. appearance codes): N(0, 1).
    Embedding { rows: usize, dim: usize },
    /// Zeros (e.g. camera pose corrections).
    Zeros { len: usize },
}

impl SlotKind {
    pub fn len(&self) -> usize {
        match self {
            Self::HashTable { len } | Self::Zeros { len } => *len,
            Self::Mlp { matrices } => matrices.iter().map(|m| m.fan_in * m.fan_out).sum(),
            Self::Embedding { rows, dim } => rows * dim,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn tag(&self) -> u32 {
        match self {
            Self::HashTable { .. } => 0,
            Self::Mlp { .. } => 1,
            Self::Embedding { .. } => 2,
            Self::Zeros { .. } => 3,
        }
    }
}

/// A slot to lay out: its name (unique in the model), kind and group (by name).
#[derive(Clone, Debug, PartialEq)]
pub struct SlotDesc {
    pub name: String,
    pub kind: SlotKind,
    pub group: String,
}

impl SlotDesc {
    pub fn new(name: &str, kind: SlotKind, group: &str) -> Self {
        Self { name: name.to_owned(), kind, group: group.to_owned() }
    }
}

/// A laid-out slot: elements `[offset, offset + len)` of each of the store's arrays.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSlot {
    pub name: String,
    pub offset: usize,
    pub len: usize,
    /// Index into the store's groups.
    pub group: usize,
    pub kind: SlotKind,
}

impl ParamSlot {
    pub fn range(&self) -> Range<usize> {
        self.offset..self.offset + self.len
    }
}

/// Slot offsets for a given chunk size (see the module documentation for the guarantees).
#[derive(Clone, Debug, PartialEq)]
pub struct ParamLayout {
    slots: Vec<ParamSlot>,
    group_ranges: Vec<Range<usize>>,
    len: usize,
    chunk_shift: u32,
}

impl ParamLayout {
    pub fn new(groups: &[ParamGroup], slots: &[SlotDesc], chunk_shift: u32) -> Result<Self, ParamError> {
        let err = |m: String| Err(ParamError::Layout(m));
        if !(6..=40).contains(&chunk_shift) {
            return err(format!("chunk shift {chunk_shift} outside 6..=40 (chunks must hold whole alignment units)"));
        }
        let chunk = 1usize << chunk_shift;
        for (i, g) in groups.iter().enumerate() {
            g.validate().map_err(|e| ParamError::Layout(e.to_string()))?;
            if g.name.is_empty() || g.name.len() > MAX_NAME_BYTES || groups[..i].iter().any(|o| o.name == g.name) {
                return err(format!("group name {:?} is empty, too long or repeated", g.name));
            }
        }
        for (i, s) in slots.iter().enumerate() {
            if s.name.is_empty() || s.name.len() > MAX_NAME_BYTES || slots[..i].iter().any(|o| o.name == s.name) {
                return err(format!("slot name {:?} is empty, too long or repeated", s.name));
            }
            if !groups.iter().any(|g| g.name == s.group) {
                return err(format!("slot {:?}: no group named {:?}", s.name, s.group));
            }
            let bad_mlp = matches!(&s.kind, SlotKind::Mlp { matrices } if matrices.iter().any(|m| m.fan_in == 0 || m.fan_out == 0));
            if s.kind.is_empty() || bad_mlp {
                return err(format!("slot {:?} is empty or has an empty matrix", s.name));
            }
        }
        let mut out = Vec::with_capacity(slots.len());
        let mut group_ranges = Vec::with_capacity(groups.len());
        let mut cursor = 0usize;
        for (gi, g) in groups.iter().enumerate() {
            let first = out.len();
            for s in slots.iter().filter(|s| s.group == g.name) {
                let len = s.kind.len();
                let mut offset = cursor.next_multiple_of(SLOT_ALIGN);
                if len > chunk || offset >> chunk_shift != (offset + len - 1) >> chunk_shift {
                    offset = offset.next_multiple_of(chunk);
                }
                out.push(ParamSlot { name: s.name.clone(), offset, len, group: gi, kind: s.kind.clone() });
                cursor = offset + len;
            }
            let start = out.get(first).map_or(cursor, |s: &ParamSlot| s.offset);
            group_ranges.push(start..cursor);
        }
        Ok(Self { slots: out, group_ranges, len: cursor, chunk_shift })
    }

    /// Total elements of each array (including padding).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn chunk_shift(&self) -> u32 {
        self.chunk_shift
    }

    pub fn slots(&self) -> &[ParamSlot] {
        &self.slots
    }

    pub fn slot(&self, name: &str) -> Option<&ParamSlot> {
        self.slots.iter().find(|s| s.name == name)
    }

    /// The element range covering every slot of group `g` (empty for a group without slots).
    pub fn group_range(&self, g: usize) -> Range<usize> {
        self.group_ranges[g].clone()
    }

    /// Splits an element range by chunk: (chunk index, range local to that chunk), in order.
    pub fn chunk_ranges(&self, range: Range<usize>) -> Vec<(usize, Range<usize>)> {
        let chunk = 1usize << self.chunk_shift;
        let mut out = Vec::new();
        let mut i = range.start;
        while i < range.end {
            let c = i >> self.chunk_shift;
            let end = range.end.min((c + 1) * chunk);
            out.push((c, i - c * chunk..end - c * chunk));
            i = end;
        }
        out
    }
}

/// Creation parameters of a [`ParamStore`].
#[derive(Clone, Debug)]
pub struct ParamStoreDesc<'a> {
    /// Names the buffers ("{name} params", ...).
    pub name: &'a str,
    pub groups: Vec<ParamGroup>,
    pub slots: Vec<SlotDesc>,
    pub seed: u64,
    /// Elements per chunk as log2; None: as large as one binding allows (what `LargeArray::new` picks).
    pub chunk_shift: Option<u32>,
}

/// The parameters, gradients and Adam state of one model (see the module documentation).
pub struct ParamStore {
    ctx: Context,
    layout: ParamLayout,
    groups: Vec<ParamGroup>,
    params: LargeArray<f32>,
    grads: LargeArray<f32>,
    m: LargeArray<f32>,
    v: LargeArray<f32>,
    group_steps: Vec<u64>,
    schedule_step: u64,
    run_progress: Option<f64>,
}

/// The chunk shift `LargeArray::new` would choose for f32 on this device.
pub fn default_chunk_shift(ctx: &Context) -> u32 {
    let caps = ctx.caps();
    chunk_shift_for(caps.max_storage_buffer_range, caps.max_memory_allocation_size)
}

/// The f32 chunk shift for a device with these limits: the largest power of two of elements one binding and one
/// allocation hold (what [`default_chunk_shift`] computes from a context, and the planner from a profile).
pub fn chunk_shift_for(max_storage_buffer_range: u64, max_memory_allocation_size: u64) -> u32 {
    let max_elems = (max_storage_buffer_range.min(max_memory_allocation_size) / 4).max(1);
    63 - max_elems.leading_zeros()
}

impl ParamStore {
    /// Lays out the slots, allocates the four arrays and initialises them (parameters from `desc.seed`,
    /// everything else zero, step counters zero).
    pub fn new(ctx: &Context, desc: &ParamStoreDesc) -> Result<Self, ParamError> {
        let shift = desc.chunk_shift.unwrap_or_else(|| default_chunk_shift(ctx));
        let layout = ParamLayout::new(&desc.groups, &desc.slots, shift)?;
        let n = layout.len();
        let arr =
            |what: &str, cat| LargeArray::<f32>::with_chunk_shift(ctx, &format!("{} {what}", desc.name), n, cat, shift);
        let store = Self {
            ctx: ctx.clone(),
            params: arr("params", MemoryCategory::Parameters)?,
            grads: arr("grads", MemoryCategory::Gradients)?,
            m: arr("adam m", MemoryCategory::OptimizerState)?,
            v: arr("adam v", MemoryCategory::OptimizerState)?,
            group_steps: vec![0; desc.groups.len()],
            schedule_step: 0,
            run_progress: None,
            groups: desc.groups.clone(),
            layout,
        };
        let mut rec = ctx.recorder("param store zero")?;
        for a in [&store.params, &store.grads, &store.m, &store.v] {
            zero_array(&mut rec, a)?;
        }
        rec.submit_and_wait()?;
        store.init_params(desc.seed)?;
        Ok(store)
    }

    /// Writes each slot's initial values (parameters only; padding, moments and gradients stay as they are).
    fn init_params(&self, seed: u64) -> GpuResult<()> {
        for slot in &self.layout.slots {
            let mut rng = slot_rng(seed, &slot.name);
            let segments: Vec<(usize, Init)> = match &slot.kind {
                SlotKind::HashTable { len } => vec![(*len, Init::Uniform(HASH_INIT_SCALE as f64))],
                SlotKind::Mlp { matrices } => matrices
                    .iter()
                    .map(|m| (m.fan_in * m.fan_out, Init::Uniform((6.0 / (m.fan_in + m.fan_out) as f64).sqrt())))
                    .collect(),
                SlotKind::Embedding { rows, dim } => vec![(rows * dim, Init::Normal)],
                SlotKind::Zeros { .. } => continue,
            };
            let mut offset = slot.offset;
            let mut spare = None;
            for (len, init) in segments {
                let mut done = 0;
                while done < len {
                    let n = PIECE.min(len - done);
                    let piece: Vec<f32> = (0..n).map(|_| init.sample(&mut rng, &mut spare)).collect();
                    self.params.upload(&self.ctx, offset + done, &piece)?;
                    done += n;
                }
                offset += len;
            }
        }
        Ok(())
    }

    pub fn context(&self) -> &Context {
        &self.ctx
    }

    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }

    /// Total elements of each array (including padding).
    pub fn len(&self) -> usize {
        self.layout.len()
    }

    pub fn is_empty(&self) -> bool {
        self.layout.is_empty()
    }

    pub fn slots(&self) -> &[ParamSlot] {
        self.layout.slots()
    }

    pub fn slot(&self, name: &str) -> Option<&ParamSlot> {
        self.layout.slot(name)
    }

    pub fn groups(&self) -> &[ParamGroup] {
        &self.groups
    }

    pub fn params(&self) -> &LargeArray<f32> {
        &self.params
    }

    pub fn grads(&self) -> &LargeArray<f32> {
        &self.grads
    }

    /// Adam's first moments.
    pub fn m(&self) -> &LargeArray<f32> {
        &self.m
    }

    /// Adam's second moments.
    pub fn v(&self) -> &LargeArray<f32> {
        &self.v
    }

    /// Adam steps each group has taken (torch's per-group `step`, for bias correction).
    pub fn group_steps(&self) -> &[u64] {
        &self.group_steps
    }

    /// Optimiser calls so far (nerfstudio's scheduler steps): the step the learning rates are evaluated at.
    pub fn schedule_step(&self) -> u64 {
        self.schedule_step
    }

    /// Learning rate of group `g` now: at the run progress for groups whose schedule spans the run
    /// ([`ParamGroup::over_run`]) once the trainer has set one, at the current schedule step otherwise.
    pub fn lr(&self, g: usize) -> f64 {
        let group = &self.groups[g];
        match self.run_progress {
            Some(tau) if group.over_run => group.lr_at_progress(tau),
            _ => group.lr_at(self.schedule_step),
        }
    }

    /// Sets how far through its run the training is (0 to 1: the larger of steps over the step budget and seconds
    /// over the time budget), for the groups whose schedule spans the run; `None` goes back to schedule steps.
    pub fn set_run_progress(&mut self, tau: Option<f64>) {
        self.run_progress = tau;
    }

    /// Takes back the counters of an optimiser step that the device skipped ([`crate::nn::adam::step_gated`]):
    /// the stepped groups' step counters and the schedule step go back by one.
    pub fn undo_step(&mut self, report: &[crate::nn::adam::GroupStep]) {
        for (t, g) in self.group_steps.iter_mut().zip(report) {
            if g.stepped {
                *t = t.saturating_sub(1);
            }
        }
        self.schedule_step = self.schedule_step.saturating_sub(1);
    }

    pub(crate) fn counters_mut(&mut self) -> (&mut [u64], &mut u64) {
        (&mut self.group_steps, &mut self.schedule_step)
    }

    /// Records `grads = 0` over the whole array (one fill per chunk).
    pub fn zero_grads(&self, rec: &mut Recorder) -> GpuResult<()> {
        zero_array(rec, &self.grads)
    }

    /// A slot of one of the store's arrays as a single binding (a slice of its chunk). Fails for a slot longer
    /// than a chunk (reach those through the chunk table).
    pub fn slot_binding(&self, array: &LargeArray<f32>, slot: &ParamSlot) -> GpuResult<Binding> {
        let pieces = self.layout.chunk_ranges(slot.range());
        match (array.len() == self.len() && array.chunk_shift() == self.layout.chunk_shift(), pieces.as_slice()) {
            (true, [(c, r)]) => array.chunks()[*c].slice(r.start, r.end),
            _ => Err(GpuError::Buffer {
                name: array.name().to_owned(),
                msg: format!("slot {:?} is not one chunk of this store's arrays", slot.name),
            }),
        }
    }

    /// Reads one slot of one of the store's arrays back.
    pub fn download_slot(&self, array: &LargeArray<f32>, slot: &ParamSlot) -> GpuResult<Vec<f32>> {
        let mut out = Vec::with_capacity(slot.len);
        for (c, r) in self.layout.chunk_ranges(slot.range()) {
            out.extend(self.ctx.download_range(&array.chunks()[c], r.start, r.end)?);
        }
        Ok(out)
    }

    /// Writes one slot of one of the store's arrays.
    pub fn upload_slot(&self, array: &LargeArray<f32>, slot: &ParamSlot, data: &[f32]) -> GpuResult<()> {
        if data.len() != slot.len {
            return Err(GpuError::Buffer {
                name: array.name().to_owned(),
                msg: format!("slot {:?} holds {} values, {} given", slot.name, slot.len, data.len()),
            });
        }
        array.upload(&self.ctx, slot.offset, data)
    }
}

fn zero_array(rec: &mut Recorder, a: &LargeArray<f32>) -> GpuResult<()> {
    for c in a.chunks().iter().filter(|c| !c.is_empty()) {
        ops::fill(rec, c, 0.0f32, 0, c.len())?;
    }
    Ok(())
}

#[derive(Copy, Clone)]
enum Init {
    Uniform(f64),
    Normal,
}

impl Init {
    fn sample(self, rng: &mut ChaCha8Rng, spare: &mut Option<f64>) -> f32 {
        match self {
            Init::Uniform(a) => ((rng.random::<f64>() * 2.0 - 1.0) * a) as f32,
            Init::Normal => {
                if let Some(z) = spare.take() {
                    return z as f32;
                }
                // Box-Muller: u1 in (0, 1] keeps ln finite.
                let u1 = 1.0 - rng.random::<f64>();
                let u2 = rng.random::<f64>();
                let r = (-2.0 * u1.ln()).sqrt();
                let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
                *spare = Some(r * s);
                (r * c) as f32
            }
        }
    }
}

/// The generator of one slot: ChaCha8 from the seed, on a stream named by the slot (FNV-1a of its name), so a
/// slot's values do not depend on the other slots.
fn slot_rng(seed: u64, name: &str) -> ChaCha8Rng {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in name.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(h);
    rng
}
