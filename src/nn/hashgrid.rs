//! Multiresolution hash encoding (instant-ngp / tiny-cuda-nn `HashGrid`, spec/nerfacto.md §3).
//!
//! [`HashGridConfig`] computes tcnn's level table (vertex-count resolutions, dense levels where res^3 fits the
//! table, CoherentPrime hashing otherwise, entries padded to multiples of 8). [`HashGrid`] records the kernels:
//! - `hashgrid_fwd`: per level (the default on CPU devices), one dispatch per level (its table is what the dispatch
//!   reads: tcnn's cache-friendly order), the level's parameters in push constants (on lavapipe read once for all
//!   invocations, not once per lane), one invocation per point; writes F features per row, and the last level the
//!   padding columns. The levels are one [`Recorder::independent`] group: no barrier among them (they write
//!   disjoint columns).
//! - `hashgrid_bwd`: gradient to the parameters, fp32 `atomicAdd` into the gradient array, one dispatch per level
//!   as the forward, also one independent group (each level adds into its own range). With texel reads (CPU
//!   devices) its `_prefetch` variant first gathers the point's 8 corner entries of the gradient table as texels
//!   and makes the atomics' addresses depend on them: the cache misses overlap in the gathers instead of each
//!   locked add waiting for its own (1.2-1.6x on lavapipe, docs/benchmarks.md). `hashgrid_bwd_runs` combines
//!   runs of consecutive points in one cell first: the default on GPUs (8 points per invocation; 1.1-1.9x on an
//!   H100, where the atomics contend), not on CPU devices (slower on lavapipe); see [`default_backward_run`].
//! - `hashgrid_bwd_input`: gradient to the positions, per level (the default on CPU devices) one dispatch per level
//!   (the first writes, the others add), one invocation per point.
//! - `_texel` variants of the forward and the input gradient read a level's table as a uniform texel buffer of
//!   the chunk holding it ([`LargeArray::texel_binding`]) instead of through its device address: on lavapipe a
//!   texel fetch is a branch-free gather. Levels that straddle chunks keep the device-address read.
//! - `_levels` variants of the forward and the input gradient: one dispatch for all the grid's levels (the forward
//!   z over levels, as tcnn's blockIdx.y; the input gradient one invocation per point walking the levels), the
//!   level table read from a buffer. The default on GPUs for passes of at most [`GPU_ONE_DISPATCH_MAX_POINTS`]
//!   points, where one level's dispatch fills little of the chip and the input gradient's levels each waited on a
//!   barrier; larger passes keep the per-level kernels, which know each level at compile time; see
//!   [`default_one_dispatch`].
//!
//! Coarse-to-fine ([`HashGrid::set_active_levels`], `field.coarse_to_fine`): every kernel multiplies level l's
//! features, or their gradients, by clamp(active - l, 0, 1), a push constant (1 by default).
//!
//! Parameters and gradients live in chunked [`LargeArray`]s (Table 1's grid is 256 MiB) at `param_offset`.

use super::SettingError;
use super::{vec_width, ParamSlice, RowSlice};
use crate::gpu::{Binding, BufferDesc, GpuBuffer, GpuError, GpuResult, Kernel, LargeArray, MemoryCategory, Recorder};
use crate::shaders;
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HashGridConfig {
    pub n_levels: u32,
    pub features_per_level: u32,
    pub log2_hashmap_size: u32,
    pub base_resolution: u32,
    pub max_resolution: u32,
}

/// One level of the table, laid out as the kernels read it (`HashLevel` in hashgrid_common.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, PartialEq, Pod, Zeroable)]
pub struct HashLevel {
    pub scale: f32,
    pub res: u32,
    pub entries: u32,
    pub offset: u32,
    pub hashed: u32,
    pub pad: [u32; 3],
}

/// Largest grid resolution per axis: a level's cell count (res^3) must stay inside the u64 sums and the kernels'
/// 32-bit cell coordinates; 2^20 is 256x nerfacto's 4096.
pub const MAX_RESOLUTION: u32 = 1 << 20;

impl HashGridConfig {
    /// nerfstudio's growth factor b = exp((ln N_max - ln N_min) / (L - 1)).
    pub fn per_level_scale(&self) -> f64 {
        if self.n_levels <= 1 {
            return 1.0;
        }
        ((self.max_resolution as f64).ln() - (self.base_resolution as f64).ln())
            .exp()
            .powf(1.0 / (self.n_levels - 1) as f64)
    }

    pub fn validate(&self) -> Result<(), SettingError> {
        let f = self.features_per_level;
        if self.n_levels == 0 || self.n_levels > 32 {
            return Err(SettingError::new("n_levels", format!("must be 1..=32, got {}", self.n_levels)));
        }
        if ![1, 2, 4, 8].contains(&f) {
            return Err(SettingError::new("features_per_level", format!("must be 1, 2, 4 or 8, got {f}")));
        }
        if !(8..=24).contains(&self.log2_hashmap_size) {
            return Err(SettingError::new(
                "log2_hashmap_size",
                format!("must be 8..=24, got {}", self.log2_hashmap_size),
            ));
        }
        if self.max_resolution > MAX_RESOLUTION {
            return Err(SettingError::new(
                "max_resolution",
                format!("must be at most {MAX_RESOLUTION} (2^20 cells per axis), got {}", self.max_resolution),
            ));
        }
        if self.base_resolution < 2 || self.max_resolution < self.base_resolution {
            return Err(SettingError::new(
                "base_resolution/max_resolution",
                format!(
                    "need 2 <= base_resolution <= max_resolution, got {} and {}",
                    self.base_resolution, self.max_resolution
                ),
            ));
        }
        Ok(())
    }

    /// The level table (tcnn: scale_l = 2^(l log2 b) N_min - 1 in f32, res_l = ceil(scale_l) + 1).
    pub fn levels(&self) -> Vec<HashLevel> {
        let log2_b = (self.per_level_scale() as f32).log2();
        let table = 1u64 << self.log2_hashmap_size;
        let mut offset = 0u64;
        (0..self.n_levels)
            .map(|l| {
                let scale = (l as f32 * log2_b).exp2() * self.base_resolution as f32 - 1.0;
                let res = scale.ceil() as u64 + 1;
                let dense = res.pow(3).min((1u64 << 31) - 1).next_multiple_of(8);
                let entries = dense.min(table);
                let lv = HashLevel {
                    scale,
                    res: res as u32,
                    entries: entries as u32,
                    offset: offset as u32,
                    hashed: u32::from(entries < res.pow(3)),
                    pad: [0; 3],
                };
                offset += entries;
                lv
            })
            .collect()
    }

    /// Table entries over all levels.
    pub fn n_entries(&self) -> usize {
        self.levels().iter().map(|l| l.entries as usize).sum()
    }

    /// Trainable floats (entries x features).
    pub fn n_params(&self) -> usize {
        self.n_entries() * self.features_per_level as usize
    }

    /// Encoded width L x F.
    pub fn n_output(&self) -> usize {
        (self.n_levels * self.features_per_level) as usize
    }
}

/// Where the encoding lands in the output rows.
#[derive(Copy, Clone, Debug)]
pub struct OutputSlot {
    pub stride: usize,
    pub col: usize,
    /// Columns written from `col`, padding included (>= L x F).
    pub pad_to: usize,
    pub pad_value: f32,
}

crate::push_constants! {
    struct FwdPush {
        params: u64,
        shift: u32,
        param_offset: u32,
        n: u32,
        out_stride: u32,
        out_col: u32,
        pad_value: f32,
        scale: f32,
        res: u32,
        entries: u32,
        /// The level's coarse-to-fine weight ([`HashGrid::level_weight`]).
        weight: f32,
    }
}

crate::push_constants! {
    struct LevelBwdPush {
        /// Chunk table of the gradient array (hashgrid_bwd) or of the parameters (hashgrid_bwd_input).
        table: u64,
        shift: u32,
        param_offset: u32,
        n: u32,
        dy_stride: u32,
        dy_col: u32,
        scale: f32,
        res: u32,
        entries: u32,
        /// The level's coarse-to-fine weight ([`HashGrid::level_weight`]).
        weight: f32,
        /// Zero: `hashgrid_bwd_prefetch` ANDs its table reads with it, so the atomics depend on them.
        zero: u32,
    }
}

crate::push_constants! {
    /// `hashgrid_fwd_levels`: the grid's first float and column; level l's weight is clamp(active - l, 0, 1).
    struct FwdLevelsPush {
        params: u64,
        shift: u32,
        param_offset: u32,
        n: u32,
        out_stride: u32,
        out_col: u32,
        pad_value: f32,
        active_levels: f32,
        pad0: u32,
    }
}

crate::push_constants! {
    /// `hashgrid_bwd_input_levels`: the grid's first float and dL/dy column, as [`FwdLevelsPush`].
    struct InputLevelsPush {
        table: u64,
        shift: u32,
        param_offset: u32,
        n: u32,
        dy_stride: u32,
        dy_col: u32,
        active_levels: f32,
        n_levels: u32,
        pad0: u32,
    }
}

crate::push_constants! {
    struct BwdPush {
        grads: u64,
        shift: u32,
        param_offset: u32,
        n: u32,
        dy_stride: u32,
        dy_col: u32,
        /// [`HashGrid::active_levels`]: level l's weight is clamp(active_levels - l, 0, 1).
        active_levels: f32,
    }
}

pub struct HashGrid {
    pub config: HashGridConfig,
    levels: GpuBuffer<HashLevel>,
    /// `hashgrid_bwd_runs`, built only when `bwd_run` > 1 (the default on GPUs; see [`default_backward_run`]).
    bwd_runs: Option<Kernel<BwdPush>>,
    /// Consecutive points one `hashgrid_bwd` invocation combines (1: one point per invocation).
    bwd_run: u32,
    /// The forward and the input gradient read each level's table as a texel buffer where the level lies in one
    /// chunk (the `_texel` kernel variants); see [`default_texel_reads`].
    texel_reads: bool,
    /// The forward and the input gradient of at most this many points record one dispatch for all levels (the
    /// `_levels` kernel variants) instead of one per level (0: never); see [`default_one_dispatch`]. Takes
    /// precedence over `texel_reads`.
    one_dispatch_max: usize,
    /// Coarse-to-fine (`field.coarse_to_fine`): level l's features are multiplied by clamp(active - l, 0, 1) in
    /// the forward and its gradients alike; `n_levels` (every weight 1) unless set.
    active: std::cell::Cell<f32>,
}

/// Points per `hashgrid_bwd` invocation: `MSNERF_HASH_BWD_RUN` when set, else 1 on CPU devices and
/// [`GPU_BACKWARD_RUN`] on GPUs. Training hands the grid a ray's samples one after another, so at coarse levels
/// neighbouring points share a cell: combining them saves contended atomics on a GPU (an H100: 1.1-1.9x per grid,
/// 5 % of a Table 1 step), while on lavapipe the extra loop costs more than the atomics it saves
/// (docs/benchmarks.md). A value that is not a positive number is an error naming the variable.
pub fn default_backward_run(ctx: &crate::gpu::Context) -> GpuResult<u32> {
    match &crate::util::env::settings().hash_bwd_run {
        None => Ok(if ctx.caps().is_cpu { 1 } else { GPU_BACKWARD_RUN }),
        Some(v) => v.trim().parse().ok().filter(|&n: &u32| n >= 1).ok_or_else(|| GpuError::Config {
            what: "MSNERF_HASH_BWD_RUN".into(),
            msg: format!("{v:?} is not a positive number of points"),
        }),
    }
}

/// Points per backward invocation on GPUs (measured on an H100 against 4 and 16; docs/benchmarks.md).
pub const GPU_BACKWARD_RUN: u32 = 8;

fn check_array(a: &LargeArray<f32>, offset: usize, n_params: usize) -> GpuResult<()> {
    if offset + n_params > a.len() || offset % 8 != 0 {
        return Err(GpuError::Buffer {
            name: a.name().into(),
            msg: format!("hash grid of {n_params} floats at {offset} does not fit (or offset not a multiple of 8)"),
        });
    }
    Ok(())
}

/// Where a grid of `len` floats at `offset` of `a` is read from: the address of its chunk and the offset in it when
/// the grid lies inside one chunk (`false`), else the chunk table's address and the offset in the array (`true`).
fn grid_base(a: &LargeArray<f32>, offset: usize, len: usize) -> GpuResult<(u64, usize, bool)> {
    let shift = a.chunk_shift();
    let (first, last) = (offset >> shift, (offset + len.max(1) - 1) >> shift);
    if first == last {
        Ok((a.chunks()[first].device_address()?, offset & ((1usize << shift) - 1), false))
    } else {
        Ok((a.table_address()?, offset, true))
    }
}

/// Where one level's dispatch reads its table: level index and table, the address and offset `grid_base` gives,
/// and the chunk holding the whole level (when one does).
struct LevelRead {
    l: usize,
    lv: HashLevel,
    base: u64,
    offset: usize,
    chunked: bool,
    chunk: usize,
}

/// Texel format of one hash table entry (F floats) for the `_texel` kernel variants.
fn texel_format(f: u32) -> ash::vk::Format {
    match f {
        1 => ash::vk::Format::R32_SFLOAT,
        2 => ash::vk::Format::R32G32_SFLOAT,
        _ => ash::vk::Format::R32G32B32A32_SFLOAT,
    }
}

/// Whether the hash grid kernels read tables as texel buffers on this device: `MSNERF_HASH_TEXEL` (`1` or `0`)
/// when set, else on CPU devices (lavapipe), where a texel fetch is a branch-free gather and a buffer read through
/// a device address a loop over the lanes with a branch each (docs/benchmarks.md). A value other than 0 or 1 is an
/// error naming the variable.
pub fn default_texel_reads(ctx: &crate::gpu::Context) -> GpuResult<bool> {
    match crate::util::env::settings().hash_texel.as_deref() {
        None => Ok(ctx.caps().is_cpu),
        Some("0") => Ok(false),
        Some("1") => Ok(true),
        Some(v) => Err(GpuError::Config { what: "MSNERF_HASH_TEXEL".into(), msg: format!("{v:?} is not 0 or 1") }),
    }
}

/// Points per pass up to which a GPU records a grid's forward and input gradient as one dispatch for all levels:
/// 2^20, 4,096 rays of 256 samples. On an H100 (docs/benchmarks.md, 2026-11-28), one dispatch was faster for every
/// grid of nerfacto at 4,096 rays (196,608 to 1,048,576 points: forward 0.40 against 0.45 ms per step, input
/// gradient 0.14 against 0.23) and for the input gradient of 196,608 points (Table 1 in 4,096-ray passes: 2.13
/// against 3.17), and slower for every grid of Table 1 at 32,768 rays in one pass (1.57 to 16.8 million points:
/// forward 6.61 against 5.89 ms, input gradient 2.36 against 2.20). The limit lies between those measured sizes;
/// passes between 1 and 1.57 million points were not measured alone. A large pass fills the chip level by level,
/// and the per-level kernels know at compile time whether a level is hashed and take its parameters from push
/// constants.
pub const GPU_ONE_DISPATCH_MAX_POINTS: usize = 1 << 20;

/// The most points per pass for which the forward and the input gradient record one dispatch for all of a grid's
/// levels (0: never; `usize::MAX`: always): `MSNERF_HASH_ONE_DISPATCH=1` always, `=0` never; else
/// [`GPU_ONE_DISPATCH_MAX_POINTS`] on GPUs, where one level's points of a small pass fill little of the chip and
/// the input gradient's levels each waited on a barrier, and never on CPU devices, where the per-level kernels keep
/// their texel reads and their level parameters in push constants (read once per dispatch, not once per lane).
/// A value other than 0 or 1 is an error naming the variable.
pub fn default_one_dispatch(ctx: &crate::gpu::Context) -> GpuResult<usize> {
    match crate::util::env::settings().hash_one_dispatch.as_deref() {
        None if ctx.caps().is_cpu => Ok(0),
        None => Ok(GPU_ONE_DISPATCH_MAX_POINTS),
        Some("0") => Ok(0),
        Some("1") => Ok(usize::MAX),
        Some(v) => {
            Err(GpuError::Config { what: "MSNERF_HASH_ONE_DISPATCH".into(), msg: format!("{v:?} is not 0 or 1") })
        }
    }
}

impl HashGrid {
    pub fn new(ctx: &crate::gpu::Context, config: &HashGridConfig) -> GpuResult<Self> {
        Self::with_backward_run(ctx, config, default_backward_run(ctx)?)
    }

    /// As [`HashGrid::new`], with `run` consecutive points per parameter-gradient invocation (1: hashgrid_bwd.comp;
    /// more: hashgrid_bwd_runs.comp).
    pub fn with_backward_run(ctx: &crate::gpu::Context, config: &HashGridConfig, run: u32) -> GpuResult<Self> {
        config.validate().map_err(|e| GpuError::Config { what: "hash grid config".into(), msg: e.to_string() })?;
        if !(1..=64).contains(&run) {
            return Err(GpuError::Buffer {
                name: "hash grid".into(),
                msg: format!("backward run {run} not in 1..=64"),
            });
        }
        let levels = GpuBuffer::from_slice(ctx, "hash grid levels", MemoryCategory::Other, &config.levels())?;
        Ok(Self {
            config: config.clone(),
            levels,
            bwd_runs: if run > 1 {
                Some(Kernel::with_spec(
                    ctx,
                    &shaders::HASHGRID_BWD_RUNS,
                    &[("F", config.features_per_level), ("RUN", run)],
                )?)
            } else {
                None
            },
            bwd_run: run,
            texel_reads: default_texel_reads(ctx)?,
            one_dispatch_max: default_one_dispatch(ctx)?,
            active: std::cell::Cell::new(config.n_levels as f32),
        })
    }

    /// Coarse-to-fine: the levels the forward and the backward record from now on use, as a real number (level l
    /// gets weight clamp(active - l, 0, 1); `n_levels` or more: all of them, the default). Held-back levels encode
    /// zeros and get no gradient (BARF, Lin et al. 2021; Neuralangelo, Li et al. 2023).
    pub fn set_active_levels(&self, active: f32) {
        self.active.set(active.clamp(0.0, self.config.n_levels as f32));
    }

    /// See [`HashGrid::set_active_levels`].
    pub fn active_levels(&self) -> f32 {
        self.active.get()
    }

    /// Level `l`'s coarse-to-fine weight: clamp(active - l, 0, 1).
    pub fn level_weight(&self, l: usize) -> f32 {
        (self.active.get() - l as f32).clamp(0.0, 1.0)
    }

    /// The chunk holding a level's table as a texel buffer for the per-level kernels, when this grid reads texels,
    /// the level lies in one chunk and the device can bind that chunk so. The one-dispatch forward and input
    /// gradient return before asking; the parameter gradient (per level on CPU devices) asks whenever it runs per
    /// level, for its prefetch.
    fn table_texels(&self, array: &LargeArray<f32>, chunked: bool, chunk: usize) -> GpuResult<Option<Binding>> {
        if !self.texel_reads || chunked {
            return Ok(None);
        }
        array.texel_binding(chunk, texel_format(self.config.features_per_level))
    }

    /// How many of the grid's levels, stored at `params`, the per-level kernels read as texels: the forward and the
    /// input gradient when they run per level (not with one dispatch for all levels), and the parameter gradient's
    /// prefetch (0 with texel reads off; tests check that the texel kernels run).
    pub fn texel_levels(&self, params: ParamSlice) -> GpuResult<usize> {
        let mut n = 0;
        for r in self.level_reads(params.array, params.offset)? {
            n += usize::from(self.table_texels(params.array, r.chunked, r.chunk)?.is_some());
        }
        Ok(n)
    }

    /// Chooses how the forward and the input gradient read the tables (tests and benchmarks compare both).
    pub fn set_texel_reads(&mut self, on: bool) {
        self.texel_reads = on;
    }

    /// Chooses between one dispatch for all levels at every size and one per level (tests and benchmarks compare
    /// both).
    pub fn set_one_dispatch(&mut self, on: bool) {
        self.one_dispatch_max = if on { usize::MAX } else { 0 };
    }

    /// Sets the most points per pass recorded as one dispatch for all levels (0: never).
    pub fn set_one_dispatch_max_points(&mut self, max: usize) {
        self.one_dispatch_max = max;
    }

    /// The most points per pass the forward and the input gradient record as one dispatch for all levels (0:
    /// never; `usize::MAX`: always).
    pub fn one_dispatch_max_points(&self) -> usize {
        self.one_dispatch_max
    }

    /// Whether a pass of `n` points records one dispatch for all levels.
    pub fn one_dispatch_for(&self, n: usize) -> bool {
        n <= self.one_dispatch_max
    }

    /// Workgroups for `n` invocations (folded into x and y) of every level (z).
    fn grid<P: Pod>(&self, rec: &Recorder, kernel: &Kernel<P>, n: usize) -> GpuResult<[u32; 3]> {
        let groups = kernel.groups_for(n as u64);
        let caps = rec.context().caps();
        let [x, y, _] = crate::gpu::kernel::fold_groups(groups, caps.max_workgroup_count).ok_or_else(|| {
            GpuError::Dispatch { kernel: "hashgrid".into(), msg: format!("{n} points need too many groups") }
        })?;
        Ok([x, y, self.config.n_levels])
    }

    /// Records the encoding of `n` positions (float[3n] in [0,1]^3) into `out`.
    pub fn forward(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        positions: &GpuBuffer<f32>,
        n: usize,
        out: &GpuBuffer<f32>,
        slot: OutputSlot,
    ) -> GpuResult<()> {
        let (params, param_offset) = (params.array, params.offset);
        check_array(params, param_offset, self.config.n_params())?;
        if slot.pad_to < self.config.n_output() || slot.col + slot.pad_to > slot.stride || n * slot.stride > out.len() {
            return Err(GpuError::Buffer {
                name: out.name().into(),
                msg: format!("output slot {slot:?} does not fit"),
            });
        }
        if n == 0 {
            return Ok(());
        }
        let c = &self.config;
        if self.one_dispatch_for(n) {
            let (base, offset, chunked) = grid_base(params, param_offset, c.n_params())?;
            let spec = [
                ("F", c.features_per_level),
                ("HASH_CHUNKED", u32::from(chunked)),
                ("PAD", (slot.pad_to - c.n_output()) as u32),
                ("VEC_OUT", vec_width(&[slot.stride, slot.col, c.features_per_level as usize])),
            ];
            let kernel = Kernel::<FwdLevelsPush>::with_spec(rec.context(), &shaders::HASHGRID_FWD_LEVELS, &spec)?;
            let push = FwdLevelsPush {
                params: base,
                shift: params.chunk_shift(),
                param_offset: offset as u32,
                n: n as u32,
                out_stride: slot.stride as u32,
                out_col: slot.col as u32,
                pad_value: slot.pad_value,
                active_levels: self.active.get(),
                pad0: 0,
            };
            let bindings = [positions.binding(), out.binding(), self.levels.binding()];
            let grid = self.grid(rec, &kernel, n)?;
            return rec.dispatch_groups("hashgrid_fwd", &kernel, &bindings, &params.deps(), &push, grid);
        }
        let f = c.features_per_level as usize;
        let levels = self.level_reads(params, param_offset)?;
        // The levels write disjoint columns of `out`: no barrier among them.
        rec.independent(|rec| {
            for LevelRead { l, lv, base, offset, chunked, chunk } in levels {
                let col = slot.col + l * f;
                let texel = self.table_texels(params, chunked, chunk)?;
                let pad = if l + 1 == c.n_levels as usize { slot.pad_to - c.n_output() } else { 0 };
                let mut spec = vec![
                    ("F", c.features_per_level),
                    ("HASHED", lv.hashed),
                    ("PAD", pad as u32),
                    ("VEC_OUT", vec_width(&[slot.stride, col])),
                ];
                // The texel variant declares no HASH_CHUNKED (it reads the level's bound chunk).
                if texel.is_none() {
                    spec.push(("HASH_CHUNKED", u32::from(chunked)));
                }
                let blob = if texel.is_some() { &shaders::HASHGRID_FWD_TEXEL } else { &shaders::HASHGRID_FWD };
                let kernel = Kernel::<FwdPush>::with_spec(rec.context(), blob, &spec)?;
                let push = FwdPush {
                    params: base,
                    shift: params.chunk_shift(),
                    param_offset: offset as u32,
                    n: n as u32,
                    out_stride: slot.stride as u32,
                    out_col: col as u32,
                    pad_value: slot.pad_value,
                    scale: lv.scale,
                    res: lv.res,
                    entries: lv.entries,
                    weight: self.level_weight(l),
                };
                let mut bindings = vec![positions.binding(), out.binding()];
                bindings.extend(texel);
                rec.dispatch_named("hashgrid_fwd", &kernel, &bindings, &params.deps(), &push, n as u64)?;
            }
            Ok(())
        })
    }

    /// Records grads += d(encoding)/d(params)^T dL/dy.
    pub fn backward_params(
        &self,
        rec: &mut Recorder,
        grads: ParamSlice,
        positions: &GpuBuffer<f32>,
        n: usize,
        dy: RowSlice,
    ) -> GpuResult<()> {
        let (grads, param_offset) = (grads.array, grads.offset);
        let (dy, dy_stride, dy_col) = (dy.buf, dy.stride, dy.col);
        check_array(grads, param_offset, self.config.n_params())?;
        if n == 0 {
            return Ok(());
        }
        if let Some(runs) = &self.bwd_runs {
            let bindings = [positions.binding(), self.levels.binding(), dy.binding()];
            let push = BwdPush {
                grads: grads.table_address()?,
                shift: grads.chunk_shift(),
                param_offset: param_offset as u32,
                n: n as u32,
                dy_stride: dy_stride as u32,
                dy_col: dy_col as u32,
                active_levels: self.active.get(),
            };
            let grid = self.grid(rec, runs, n.div_ceil(self.bwd_run as usize))?;
            return rec.dispatch_groups("hashgrid_bwd", runs, &bindings, &grads.deps(), &push, grid);
        }
        let dy = RowSlice { buf: dy, stride: dy_stride, col: dy_col };
        self.record_level_backward(rec, (grads, param_offset), positions, n, dy, None)
    }

    /// Records dL/dp (float[3n]) from dL/dy.
    pub fn backward_input(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        positions: &GpuBuffer<f32>,
        n: usize,
        dy: RowSlice,
        dp: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let (params, param_offset) = (params.array, params.offset);
        let (dy, dy_stride, dy_col) = (dy.buf, dy.stride, dy.col);
        check_array(params, param_offset, self.config.n_params())?;
        if n == 0 {
            return Ok(());
        }
        let dy = RowSlice { buf: dy, stride: dy_stride, col: dy_col };
        if self.one_dispatch_for(n) {
            let c = &self.config;
            let (base, offset, chunked) = grid_base(params, param_offset, c.n_params())?;
            let spec = [
                ("F", c.features_per_level),
                ("HASH_CHUNKED", u32::from(chunked)),
                ("VEC_DY", vec_width(&[dy.stride, dy.col, c.features_per_level as usize])),
            ];
            let kernel =
                Kernel::<InputLevelsPush>::with_spec(rec.context(), &shaders::HASHGRID_BWD_INPUT_LEVELS, &spec)?;
            let push = InputLevelsPush {
                table: base,
                shift: params.chunk_shift(),
                param_offset: offset as u32,
                n: n as u32,
                dy_stride: dy.stride as u32,
                dy_col: dy.col as u32,
                active_levels: self.active.get(),
                n_levels: c.n_levels,
                pad0: 0,
            };
            let bindings = [positions.binding(), dy.buf.binding(), dp.binding(), self.levels.binding()];
            return rec.dispatch_named("hashgrid_bwd_input", &kernel, &bindings, &params.deps(), &push, n as u64);
        }
        self.record_level_backward(rec, (params, param_offset), positions, n, dy, Some(dp))
    }

    /// One dispatch per level of a kernel that reads the level's F columns of `dy` and the level's table entries of
    /// `array` (constants F, HASHED, HASH_CHUNKED, VEC_DY, and FIRST = first level when `dp` is given, bound third):
    /// the input gradient when `dp` is given, else the parameter gradient, each in its texel variant where the
    /// level's table has a texel view.
    fn record_level_backward(
        &self,
        rec: &mut Recorder,
        (array, param_offset): (&LargeArray<f32>, usize),
        positions: &GpuBuffer<f32>,
        n: usize,
        dy: RowSlice,
        dp: Option<&GpuBuffer<f32>>,
    ) -> GpuResult<()> {
        let c = &self.config;
        let f = c.features_per_level as usize;
        let levels = self.level_reads(array, param_offset)?;
        let record = |rec: &mut Recorder| -> GpuResult<()> {
            for LevelRead { l, lv, base, offset, chunked, chunk } in levels {
                let col = dy.col + l * f;
                // Where the forward reads the level's table as texels, the input gradient does too, and the
                // parameter gradient gathers its corners' entries of the gradient table as texels before its
                // atomics (`hashgrid_bwd_prefetch`).
                let texel = self.table_texels(array, chunked, chunk)?;
                let mut spec =
                    vec![("F", c.features_per_level), ("HASHED", lv.hashed), ("VEC_DY", vec_width(&[dy.stride, col]))];
                if texel.is_none() || dp.is_none() {
                    spec.push(("HASH_CHUNKED", u32::from(chunked)));
                }
                let mut bindings = vec![positions.binding(), dy.buf.binding()];
                if let Some(dp) = dp {
                    spec.push(("FIRST", u32::from(l == 0)));
                    bindings.push(dp.binding());
                }
                let blob = match (texel.is_some(), dp.is_some()) {
                    (false, false) => &shaders::HASHGRID_BWD,
                    (true, false) => &shaders::HASHGRID_BWD_PREFETCH,
                    (false, true) => &shaders::HASHGRID_BWD_INPUT,
                    (true, true) => &shaders::HASHGRID_BWD_INPUT_TEXEL,
                };
                bindings.extend(texel);
                let kernel = Kernel::<LevelBwdPush>::with_spec(rec.context(), blob, &spec)?;
                let push = LevelBwdPush {
                    table: base,
                    shift: array.chunk_shift(),
                    param_offset: offset as u32,
                    n: n as u32,
                    dy_stride: dy.stride as u32,
                    dy_col: col as u32,
                    scale: lv.scale,
                    res: lv.res,
                    entries: lv.entries,
                    weight: self.level_weight(l),
                    zero: 0,
                };
                let label = if dp.is_some() { "hashgrid_bwd_input" } else { "hashgrid_bwd" };
                rec.dispatch_named(label, &kernel, &bindings, &array.deps(), &push, n as u64)?;
            }
            Ok(())
        };
        match dp {
            // The parameter gradient: each level adds atomically into its own range, so the levels need no barrier
            // among them. The input gradient's levels add into the same dp rows in turn and keep theirs.
            None => rec.independent(record),
            Some(_) => record(rec),
        }
    }

    /// Every level's table in a grid stored at `param_offset` of `array`.
    fn level_reads(&self, array: &LargeArray<f32>, param_offset: usize) -> GpuResult<Vec<LevelRead>> {
        let f = self.config.features_per_level as usize;
        (self.config.levels().into_iter().enumerate())
            .map(|(l, lv)| {
                let start = param_offset + lv.offset as usize * f;
                let (base, offset, chunked) = grid_base(array, start, lv.entries as usize * f)?;
                Ok(LevelRead { l, lv, base, offset, chunked, chunk: start >> array.chunk_shift() })
            })
            .collect()
    }

    /// A scratch output buffer of `n` rows for this grid (tests and benchmarks).
    pub fn output_buffer(&self, ctx: &crate::gpu::Context, n: usize, stride: usize) -> GpuResult<GpuBuffer<f32>> {
        GpuBuffer::new(
            ctx,
            &BufferDesc { name: "hash grid output", len: n * stride, category: MemoryCategory::Activations },
        )
    }
}
