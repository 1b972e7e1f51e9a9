//! The MLP of tiny-cuda-nn's `FullyFusedMLP` semantics (spec/nerfacto.md §4): no biases, ReLU hidden layers of
//! width 16/32/64/128, any input width (padded to 16 by the caller's row layout), any output width (padded to 16 in
//! the parameter layout), output activation none / sigmoid / exponential / ReLU. Weights: row-major matrices
//! W_in (WIDTH x in_pad), N_HIDDEN-1 hidden (WIDTH x WIDTH), W_out (out_pad x WIDTH), contiguous, inside one chunk
//! of a parameter array.
//!
//! The network runs layer by layer, each layer as register tiles (`glsl/network/`):
//! - `mlp_layer_fwd`: one row per invocation, a block of a layer's outputs fully unrolled, every weight read at a
//!   constant offset from a push-constant address (shared by all invocations: a broadcast on lavapipe's SIMD, a
//!   uniform load on GPUs); hidden outputs go to the activations buffer (training) or a bounded scratch
//!   (inference, in blocks of [`INFER_BLOCK_ROWS`] rows).
//! - `mlp_out_delta` then `mlp_layer_bwd` (the same tile shape with the matrix transposed, masked by the stored
//!   ReLU activations): every layer's deltas, and the input gradient.
//! - `mlp_wgrad` + `mlp_wgrad_reduce`: weight gradients, split over the batch, summed in a fixed order
//!   (deterministic; no atomics).
//!
//! On GPUs the same products run as shared-memory tiles instead (`mlp_tile_layer` for forward and backward,
//! `mlp_tile_wgrad` for the weight gradients, then the same reduction): a workgroup of 256 stages 16-deep slices
//! of a 64 x 64 (or 256 x 16, 128 x 32) block in shared memory and each thread keeps a 4 x 4 block in registers,
//! so register use does not grow with the layer's width.
//!
//! Which family runs, and its block sizes, come from the device ([`MlpTiling::for_device`]): lavapipe compiles
//! each pipeline with LLVM, whose time grows faster than linearly with the unrolled code, so a register kernel's
//! block is kept under a multiply-add budget.
//! Rows are read and written as wide as their alignment allows (`row_io.glsl`). On CPU devices the register-tile
//! layers read their fp32 rows through texel views instead (the `_texel` variants, [`MlpTiling::texel_rows`]): a
//! branch-free gather on lavapipe, where a storage read at a per-lane address is a loop over the SIMD lanes. Why
//! this shape, and what it reaches against a CPU sgemm: docs/benchmarks.md.
//!
//! With `MlpConfig::half_activations` every kernel that writes or reads the hidden activations (forward outputs,
//! the backward pass's ReLU mask, the weight gradients' inputs) stores them as fp16 pairs in 32-bit words (spec
//! constants `HALF_*`); inputs, outputs, deltas and all arithmetic stay fp32.

use super::SettingError;
use super::{vec_width, ParamSlice, RowSlice};
use crate::gpu::{Binding, Context, DeviceCaps, GpuBuffer, GpuError, GpuResult, Kernel, LargeArray, Recorder};
use crate::shaders;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    None,
    Sigmoid,
    /// exp forward; backward derivative exp(clamp(x, -15, 15)) (nerfstudio's trunc_exp).
    Exponential,
    Relu,
}

impl Activation {
    fn code(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Sigmoid => 1,
            Self::Exponential => 2,
            Self::Relu => 3,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MlpConfig {
    pub n_input: usize,
    pub n_output: usize,
    pub width: usize,
    pub n_hidden_layers: usize,
    pub output_activation: Activation,
    /// Hidden activations stored as fp16 (the products and sums stay fp32): halves the largest buffers of a
    /// training step and the memory traffic of the layers that read them. Inputs, outputs, deltas and gradients
    /// stay fp32. The ReLU mask of the backward pass and the weight gradients use the stored fp16 values.
    #[serde(default)]
    pub half_activations: bool,
}

impl MlpConfig {
    pub fn validate(&self) -> Result<(), SettingError> {
        if ![16, 32, 64, 128].contains(&self.width) {
            return Err(SettingError::new("width", format!("must be 16, 32, 64 or 128, got {}", self.width)));
        }
        if self.n_hidden_layers == 0 || self.n_hidden_layers > 8 {
            return Err(SettingError::new("n_hidden_layers", format!("must be 1..=8, got {}", self.n_hidden_layers)));
        }
        if self.n_input == 0 || self.n_input > 256 || self.n_output == 0 || self.n_output > 256 {
            return Err(SettingError::new(
                "n_input/n_output",
                format!("must be 1..=256, got {} and {}", self.n_input, self.n_output),
            ));
        }
        Ok(())
    }

    pub fn in_pad(&self) -> usize {
        self.n_input.next_multiple_of(16)
    }

    pub fn out_pad(&self) -> usize {
        self.n_output.next_multiple_of(16)
    }

    /// (rows, columns) of every matrix, first to last.
    pub fn matrices(&self) -> Vec<(usize, usize)> {
        let mut m = vec![(self.width, self.in_pad())];
        m.extend(std::iter::repeat_n((self.width, self.width), self.n_hidden_layers - 1));
        m.push((self.out_pad(), self.width));
        m
    }

    pub fn n_params(&self) -> usize {
        self.matrices().iter().map(|(r, c)| r * c).sum()
    }

    /// Hidden activation values of `n` rows (as many hidden deltas).
    pub fn hidden_values(&self, n: usize) -> usize {
        self.n_hidden_layers * n * self.width
    }

    /// Floats of storage for the hidden activations of `n` rows: one per value, or one per two when
    /// `half_activations` (laid out as half[N_HIDDEN][n][WIDTH], strides and columns counted in halves).
    pub fn hidden_floats(&self, n: usize) -> usize {
        if self.half_activations {
            self.hidden_values(n).div_ceil(2)
        } else {
            self.hidden_values(n)
        }
    }

    /// Floats of the deltas buffer for `n` rows: hidden deltas, then output deltas (always fp32).
    pub fn delta_floats(&self, n: usize) -> usize {
        self.hidden_values(n) + n * self.out_delta_cols()
    }

    /// Columns (and row stride) of the output deltas: n_output rounded up to 4, the widest the kernels that read
    /// them need (zeros past n_output); not `out_pad`, which for one density output would store 16.
    pub fn out_delta_cols(&self) -> usize {
        self.n_output.next_multiple_of(4).min(self.out_pad())
    }

    /// Floats of the split-K scratch of the weight gradients for `n` rows.
    pub fn wgrad_scratch_floats(&self, n: usize) -> usize {
        let splits = n.div_ceil(ROWS_PER_SPLIT).max(1);
        splits * self.matrices().iter().map(|(r, c)| r * c).max().unwrap_or(0)
    }

    /// Floats of the hidden-layer scratch that inference over `n` rows needs (it runs in blocks of
    /// [`INFER_BLOCK_ROWS`] rows; a training activations buffer for as many rows is large enough too).
    pub fn infer_scratch_floats(&self, n: usize) -> usize {
        self.hidden_floats(n.min(INFER_BLOCK_ROWS))
    }

    /// (outputs, inputs) of every layer as computed: the matrices, with the last one's padding rows left out.
    pub fn layer_shapes(&self) -> Vec<(usize, usize)> {
        let mut m = self.matrices();
        if let Some(last) = m.last_mut() {
            last.0 = self.n_output;
        }
        m
    }

    /// Multiply-adds per row of a forward pass (x2 for FLOPs; the backward costs twice the forward).
    pub fn macs_per_row(&self) -> usize {
        self.layer_shapes().iter().map(|(r, c)| r * c).sum()
    }
}

/// Rows per split of the weight-gradient reduction.
pub const ROWS_PER_SPLIT: usize = 256;

/// Most splits the shared-memory weight gradient uses: past it, splits grow longer instead of more numerous. A GPU
/// runs 256 splits of a 128 x 128 matrix as 1024 workgroups, enough to fill it, and `mlp_wgrad_reduce` then sums
/// 256 partials per weight rather than one per 256 rows (on an H100, the reduction was the slowest kernel of a
/// multispectral-nerf step with 4096-ray chunks: 11 of 63 ms).
pub const MAX_TILE_SPLITS: usize = 256;

/// Rows per weight-gradient split for `n` rows: [`ROWS_PER_SPLIT`], or for the shared-memory tiles enough to keep
/// the splits within [`MAX_TILE_SPLITS`] (a multiple of 16, the rows the kernel stages at a time). Never more
/// splits than `wgrad_scratch_floats` sizes for.
fn rows_per_split(n: usize, shared_tiles: bool) -> usize {
    if shared_tiles {
        n.div_ceil(MAX_TILE_SPLITS).next_multiple_of(16).max(ROWS_PER_SPLIT)
    } else {
        ROWS_PER_SPLIT
    }
}

/// Inference runs the layers over blocks of this many rows, so its hidden-layer scratch stays bounded.
pub const INFER_BLOCK_ROWS: usize = 1 << 16;

/// Which kernels run the MLP and their block sizes on one device.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct MlpTiling {
    /// Shared-memory tiles (`mlp_tile_layer`, `mlp_tile_wgrad`: fixed register use, any width) instead of the
    /// register tiles (`mlp_layer_fwd`/`_bwd`, `mlp_wgrad`: a row's whole input in registers).
    pub shared_tiles: bool,
    /// Register tiles: most unrolled multiply-adds per row in one `mlp_layer_fwd` / `mlp_layer_bwd` pipeline: a
    /// layer whose inputs x outputs exceed it runs as several blocks of outputs, each reading the row's inputs again.
    pub mac_budget: usize,
    /// Register tiles: largest weight-gradient tile one `mlp_wgrad` invocation accumulates: rows of the matrix
    /// (outputs of the layer) ...
    pub wgrad_tile_j: usize,
    /// ... and columns (its inputs).
    pub wgrad_tile_k: usize,
    /// Register tiles: batch rows one `mlp_wgrad` loop iteration takes (unrolled).
    pub wgrad_rows: usize,
    /// Weight gradients on tensor cores (`mlp_coop_wgrad`: VK_KHR_cooperative_matrix, fp16 operands, fp32 sums)
    /// instead of `mlp_tile_wgrad`: on by default where the device has them (`DeviceCaps::cooperative_matrix`) and
    /// the build carries them (the `shaderc-from-source` feature). Needs `shared_tiles`.
    pub coop_matrix: bool,
    /// The layers' forward and backward products on tensor cores too (`mlp_coop_layer` instead of
    /// `mlp_tile_layer`). Needs `coop_matrix`. Off by default (`coop_layers=1` turns it on): fp16 activations in
    /// every layer product cost the 30 s demo 0.8 dB of held-out PSNR on an H200 (38.85 against 39.66 dB, three
    /// runs each, 2026-11-27), where tensor cores for the weight gradients alone cost nothing (39.69 dB).
    pub coop_layers: bool,
    /// Register tiles: the layers read their fp32 input rows (and the backward its deltas and activations) through
    /// R32G32B32A32 texel views (the `_texel` variants of `mlp_layer_fwd` / `mlp_layer_bwd`) where the rows start
    /// on whole texels and the device can view the buffer so. On lavapipe a texel fetch is a branch-free gather and
    /// a storage read at a per-lane address a loop over the lanes: on by default on CPU devices (docs/benchmarks.md),
    /// off on GPUs, which coalesce either read.
    pub texel_rows: bool,
}

impl MlpTiling {
    /// CPU devices' kernels and block sizes (see [`MlpTiling::for_device`]).
    pub const CPU_DEFAULTS: Self = Self {
        shared_tiles: false,
        mac_budget: 16384,
        wgrad_tile_j: 64,
        wgrad_tile_k: 64,
        wgrad_rows: 4,
        coop_matrix: false,
        coop_layers: false,
        texel_rows: true,
    };
    /// GPUs' kernels and block sizes, tensor cores aside (see [`MlpTiling::for_device`]).
    pub const GPU_DEFAULTS: Self = Self {
        shared_tiles: true,
        mac_budget: 4096,
        wgrad_tile_j: 4,
        wgrad_tile_k: 4,
        wgrad_rows: 1,
        coop_matrix: false,
        coop_layers: false,
        texel_rows: false,
    };

    /// CPU devices (lavapipe): register tiles, 16384 multiply-adds per pipeline (a 128 x 128 layer in one block:
    /// about 15 s of LLVM compile time the first time, kept by Mesa's disk cache; at 8192 it ran as two blocks each
    /// re-reading the row, and Table 1's colour head trained 15 % slower) and 64 x 64 gradient tiles taking 4 rows
    /// per iteration (16384 multiply-adds; Table 1's colour head's weight gradient takes 88-90 ms per 65,536 rows
    /// against 90-116 with 64 x 32 and 125-141 with 32 x 32, docs/benchmarks.md; short batches get smaller tiles,
    /// `register_wgrad_tile`); lavapipe's SIMD lanes each own a row, and its shared memory and barriers are slow.
    /// GPUs: shared-memory tiles. A register tile keeps a row's inputs and a block of outputs in registers: at 128
    /// inputs and an 8192 budget that is 192 live floats, which NVIDIA's compiler spills to local memory or refuses
    /// (measured on an H100: `vkCreateComputePipelines` failed), and every thread re-reads all weights. The
    /// register-tile fields below still apply when `shared=0`: 4096, 4 x 4.
    /// GPUs with cooperative matrices (and a build that carries their kernels): those for the weight gradients, on
    /// the same tiles; the layers' products stay fp32 unless `coop_layers=1` (see [`MlpTiling::coop_layers`]).
    /// `MSNERF_MLP_TILING=shared=0|1,coop=0|1,coop_layers=0|1,texel=0|1,mac_budget=N,wgrad_tile=N,wgrad_tile_j=N,wgrad_tile_k=N,wgrad_rows=N`
    /// overrides any of them (benchmarks; `wgrad_tile` sets both tile sides).
    pub fn for_device(caps: &DeviceCaps) -> GpuResult<Self> {
        let t = if caps.is_cpu {
            Self::CPU_DEFAULTS
        } else {
            let coop = coop_available(caps);
            Self { coop_matrix: coop, ..Self::GPU_DEFAULTS }
        };
        match &crate::util::env::settings().mlp_tiling {
            Some(v) => t
                .with_overrides(v)
                .map_err(|e| GpuError::Config { what: "MSNERF_MLP_TILING".into(), msg: e.to_string() }),
            None => Ok(t),
        }
    }

    /// `key=value` pairs separated by commas; keys are the field names (`shared` for `shared_tiles`, 0 or 1).
    /// `shared=0` without a `coop` key also turns the tensor cores off (they run on the shared tiles), and `coop=0`
    /// without a `coop_layers` key turns off the layers' too; asking for them explicitly where they cannot run is
    /// refused when the MLP is built.
    pub fn with_overrides(mut self, spec: &str) -> Result<Self, SettingError> {
        let (mut coop_given, mut layers_given) = (false, false);
        for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = part.split_once('=').ok_or_else(|| SettingError::new(part, "is not key=value"))?;
            let n: usize =
                value.trim().parse().map_err(|_| SettingError::new(key, format!("{value:?} is not a number")))?;
            if matches!(key.trim(), "shared" | "coop" | "coop_layers" | "texel") {
                if n > 1 {
                    return Err(SettingError::new(key.trim(), format!("{n} is not 0 or 1")));
                }
                match key.trim() {
                    "shared" => self.shared_tiles = n == 1,
                    "coop" => (self.coop_matrix, coop_given) = (n == 1, true),
                    "texel" => self.texel_rows = n == 1,
                    _ => (self.coop_layers, layers_given) = (n == 1, true),
                }
                continue;
            }
            if n == 0 || n > 1 << 16 {
                return Err(SettingError::new(key, format!("{n} is outside 1..=65536")));
            }
            match key.trim() {
                "mac_budget" => self.mac_budget = n,
                "wgrad_tile" => (self.wgrad_tile_j, self.wgrad_tile_k) = (n, n),
                "wgrad_tile_j" => self.wgrad_tile_j = n,
                "wgrad_tile_k" => self.wgrad_tile_k = n,
                "wgrad_rows" => self.wgrad_rows = n,
                other => {
                    let keys =
                        "shared, coop, coop_layers, texel, mac_budget, wgrad_tile, wgrad_tile_j, wgrad_tile_k, wgrad_rows";
                    return Err(SettingError::new(other, format!("unknown key ({keys})")));
                }
            }
        }
        if !self.shared_tiles && !coop_given && !layers_given {
            (self.coop_matrix, self.coop_layers) = (false, false);
        }
        if !self.coop_matrix && !layers_given {
            self.coop_layers = false;
        }
        Ok(self)
    }
}

/// Whether this device and this build can run the cooperative-matrix MLP kernels.
pub fn coop_available(caps: &DeviceCaps) -> bool {
    !caps.is_cpu && caps.cooperative_matrix && shaders::MLP_COOP_LAYER.is_some() && shaders::MLP_COOP_WGRAD.is_some()
}

/// Splits `total` outputs into near-equal blocks of at most `max` (a multiple of 4 when there are several).
fn blocks(total: usize, max: usize) -> Vec<Range<usize>> {
    let max = (max / 4 * 4).max(4);
    let size = if total <= max { total } else { total.div_ceil(total.div_ceil(max)).next_multiple_of(4) };
    (0..total).step_by(size.max(1)).map(|s| s..(s + size).min(total)).collect()
}

/// The largest of `max`, `max / 2`, ... (at least 1) that divides `total`.
fn tile(total: usize, max: usize) -> usize {
    let mut t = max.max(1);
    while total % t != 0 {
        t /= 2;
    }
    t
}

crate::push_constants! {
    struct LayerFwdPush {
        w_addr: u64,
        n: u32,
        in_stride: u32,
        in_col: u32,
        out_stride: u32,
        out_col: u32,
        pad: u32,
    }
}

crate::push_constants! {
    struct LayerBwdPush {
        w_addr: u64,
        n: u32,
        d_stride: u32,
        d_col: u32,
        a_stride: u32,
        a_col: u32,
        out_stride: u32,
        out_col: u32,
        pad: u32,
    }
}

crate::push_constants! {
    struct OutDeltaPush {
        n: u32,
        y_stride: u32,
        y_col: u32,
        dy_stride: u32,
        dy_col: u32,
        d_stride: u32,
        d_col: u32,
    }
}

crate::push_constants! {
    struct WgradPush {
        n: u32,
        out_w: u32,
        in_w: u32,
        d_stride: u32,
        d_col: u32,
        a_stride: u32,
        a_col: u32,
        rows_per_split: u32,
        splits: u32,
        tiles_k: u32,
    }
}

impl WgradPush {
    /// Push constants of `mlp_wgrad` and `mlp_tile_wgrad` (the same block): deltas `d` x inputs `a` over `n` rows
    /// in `splits` splits of `split_rows`, an `out_w` x `in_w` matrix in tiles with `tiles_k` along its rows.
    fn new(
        (d, a): (RowSlice, RowSlice),
        (n, split_rows, splits): (usize, usize, usize),
        (out_w, in_w): (usize, usize),
        tiles_k: usize,
    ) -> Self {
        Self {
            n: n as u32,
            out_w: out_w as u32,
            in_w: in_w as u32,
            d_stride: d.stride as u32,
            d_col: d.col as u32,
            a_stride: a.stride as u32,
            a_col: a.col as u32,
            rows_per_split: split_rows as u32,
            splits: splits as u32,
            tiles_k: tiles_k as u32,
        }
    }
}

crate::push_constants! {
    struct ReducePush {
        grads: u64,
        shift: u32,
        g_offset: u32,
        count: u32,
        splits: u32,
        pad: u32,
        pad2: u32,
    }
}

crate::push_constants! {
    struct TileLayerPush {
        w_addr: u64,
        n: u32,
        k_dim: u32,
        cols: u32,
        ws_t: u32,
        ws_c: u32,
        a_stride: u32,
        a_col: u32,
        m_stride: u32,
        m_col: u32,
        c_stride: u32,
        c_col: u32,
        col_tiles: u32,
    }
}

/// What `mlp_tile_layer` computes: a layer's forward (activation `act`) or its backward to the input (masked by the
/// ReLU that produced the input, or not masked for the network's input).
#[derive(Copy, Clone)]
enum TileOp<'a> {
    Forward(Activation),
    Backward(Option<RowSlice<'a>>),
}

/// Workgroup threads of the shared-memory tile kernels.
const TILE_THREADS: u64 = 256;

/// Workgroup threads of the cooperative-matrix kernels (four subgroups of 32) and rows of a `mlp_coop_layer` tile.
const COOP_THREADS: u64 = 128;
const COOP_ROWS: usize = 64;

/// Columns of a shared-memory tile for a result `cols` wide: 16, 32 or 64 (the tile has 4096 / that rows).
fn tile_columns(cols: usize) -> usize {
    cols.next_power_of_two().clamp(16, 64)
}

/// Buffers a training pass reads and writes besides parameters.
pub struct MlpTrainBuffers<'a> {
    /// Hidden activations, `hidden_floats(n)`.
    pub acts: &'a GpuBuffer<f32>,
    /// Deltas, `delta_floats(n)`.
    pub deltas: &'a GpuBuffer<f32>,
    /// Split-K scratch for weight gradients, `wgrad_scratch_floats(n)`.
    pub scratch: &'a GpuBuffer<f32>,
}

pub struct Mlp {
    pub config: MlpConfig,
    pub tiling: MlpTiling,
    reduce: Kernel<ReducePush>,
    /// Layer kernels recorded in their `_texel` variant so far ([`Mlp::texel_dispatches`]).
    texel_dispatches: AtomicUsize,
}

impl Mlp {
    pub fn new(ctx: &Context, config: &MlpConfig) -> GpuResult<Self> {
        Self::with_tiling(ctx, config, MlpTiling::for_device(ctx.caps())?)
    }

    /// With explicit block sizes (benchmarks and tests compare them).
    pub fn with_tiling(ctx: &Context, config: &MlpConfig, tiling: MlpTiling) -> GpuResult<Self> {
        config.validate().map_err(|e| GpuError::Config { what: "MLP config".into(), msg: e.to_string() })?;
        if (tiling.coop_matrix || tiling.coop_layers) && !(tiling.shared_tiles && coop_available(ctx.caps())) {
            let why = if !tiling.shared_tiles {
                "needs the shared-memory tiles (shared=1)".to_string()
            } else if shaders::MLP_COOP_LAYER.is_none() {
                "this build lacks its kernels (build with --features shaderc-from-source)".to_string()
            } else {
                format!(
                    "{} offers no fp16 16x16x16 cooperative matrices with 32-wide subgroups (or a validation layer \
                     older than the extension hides them)",
                    ctx.caps().name
                )
            };
            return Err(GpuError::Config {
                what: "MLP tiling coop".into(),
                msg: format!("cooperative matrices: {why}"),
            });
        }
        let reduce = Kernel::new(ctx, &shaders::MLP_WGRAD_REDUCE)?;
        Ok(Self { config: config.clone(), tiling, reduce, texel_dispatches: AtomicUsize::new(0) })
    }

    /// `buf` as an R32G32B32A32 texel binding for the layers' `_texel` variants: when this tiling reads rows as
    /// texels ([`MlpTiling::texel_rows`]), the rows are fp32 and start on whole texels (every float offset in
    /// `offsets` a multiple of 4), and the device can view the buffer so; else `None` (the storage-buffer read).
    fn texel_rows(&self, buf: &GpuBuffer<f32>, half: bool, offsets: &[usize]) -> GpuResult<Option<Binding>> {
        if !self.tiling.texel_rows || half || offsets.iter().any(|o| o % 4 != 0) {
            return Ok(None);
        }
        buf.texel_binding(ash::vk::Format::R32G32B32A32_SFLOAT)
    }

    /// How many layer kernels (`mlp_layer_fwd` / `mlp_layer_bwd` dispatches) this MLP has recorded in their
    /// `_texel` variant: tests check that the texel reads run where they should, not a silent fallback.
    pub fn texel_dispatches(&self) -> usize {
        self.texel_dispatches.load(Ordering::Relaxed)
    }

    /// Floats of the split-K scratch for `n` rows.
    pub fn wgrad_scratch_floats(&self, n: usize) -> usize {
        self.config.wgrad_scratch_floats(n)
    }

    /// The weights lie inside one chunk and start 16-byte aligned (the layer kernels read them as vec4).
    fn check_params(&self, p: &ParamSlice) -> GpuResult<()> {
        if p.offset % 4 != 0 {
            return Err(GpuError::Buffer {
                name: p.array.name().into(),
                msg: format!("MLP weights at element {} must start at a multiple of 4 elements", p.offset),
            });
        }
        check_within_chunk(p.array, p.offset, self.config.n_params())
    }

    /// Inference: output rows from input rows (`in_pad` columns read, `n_output` written), through `scratch`: in
    /// blocks of [`INFER_BLOCK_ROWS`] rows when it holds `infer_scratch_floats(n)` floats, in one block when it
    /// holds all `n` rows' hidden layers (training's activations buffer does: a proposal MLP that is not updated
    /// this step runs one dispatch per layer instead of one per layer and block, each block waiting on the last).
    pub fn infer(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        input: RowSlice,
        n: usize,
        output: RowSlice,
        scratch: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        need(scratch, self.config.infer_scratch_floats(n))?;
        let block = if scratch.len() >= self.config.hidden_floats(n) { n.max(1) } else { INFER_BLOCK_ROWS };
        for start in (0..n).step_by(block) {
            let rows = (n - start).min(block);
            self.record_forward(rec, &params, rows_from(input, start), rows, rows_from(output, start), scratch)?;
        }
        Ok(())
    }

    /// Training forward: like `infer`, keeping every hidden layer's output in `acts` (`hidden_floats(n)`).
    pub fn forward(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        input: RowSlice,
        n: usize,
        output: RowSlice,
        acts: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        need(acts, self.config.hidden_floats(n))?;
        self.record_forward(rec, &params, input, n, output, acts)
    }

    /// Every layer over `n` rows, hidden outputs into `acts` laid out as float[N_HIDDEN][n][WIDTH] (half[...] with
    /// `half_activations`).
    fn record_forward(
        &self,
        rec: &mut Recorder,
        params: &ParamSlice,
        input: RowSlice,
        n: usize,
        output: RowSlice,
        acts: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        self.check_params(params)?;
        if n == 0 {
            return Ok(());
        }
        let c = &self.config;
        let ctx = rec.context();
        let base = weights_address(params)?;
        let deps = params.array.deps();
        let hidden = RowSlice { buf: acts, stride: c.width, col: 0 };
        let offsets = matrix_offsets(c);
        for (layer, &(out_w, in_w)) in c.layer_shapes().iter().enumerate() {
            let last = layer == c.n_hidden_layers;
            let src = if layer == 0 { input } else { RowSlice { col: (layer - 1) * n * c.width, ..hidden } };
            let dst = if last { output } else { RowSlice { col: layer * n * c.width, ..hidden } };
            let act = if last { c.output_activation } else { Activation::Relu };
            let (half_in, half_out) = (c.half_activations && layer > 0, c.half_activations && !last);
            if self.tiling.shared_tiles {
                let w_addr = base + 4 * offsets[layer] as u64;
                let halves = (half_in, false, half_out);
                self.tile_layer(rec, (w_addr, &deps), TileOp::Forward(act), (src, dst, halves), n, (in_w, out_w))?;
                continue;
            }
            let texel = self.texel_rows(src.buf, half_in, &[src.stride, src.col])?;
            for b in blocks(out_w, self.tiling.mac_budget / in_w) {
                let mut spec = vec![
                    ("IN_W", in_w as u32),
                    ("JB", b.len() as u32),
                    ("ACT", act.code()),
                    ("VEC_OUT", row_vec(half_out, &[dst.stride, dst.col + b.start])),
                    ("HALF_OUT", u32::from(half_out)),
                ];
                // The texel variant reads the input through its view: no access width, never fp16.
                if texel.is_none() {
                    spec.push(("VEC_IN", row_vec(half_in, &[src.stride, src.col])));
                    spec.push(("HALF_IN", u32::from(half_in)));
                }
                let blob = if texel.is_some() { &shaders::MLP_LAYER_FWD_TEXEL } else { &shaders::MLP_LAYER_FWD };
                self.texel_dispatches.fetch_add(usize::from(texel.is_some()), Ordering::Relaxed);
                let k = Kernel::with_spec(ctx, blob, &spec)?;
                let push = LayerFwdPush {
                    w_addr: base + 4 * (offsets[layer] + b.start * in_w) as u64,
                    n: n as u32,
                    in_stride: src.stride as u32,
                    in_col: src.col as u32,
                    out_stride: dst.stride as u32,
                    out_col: (dst.col + b.start) as u32,
                    pad: 0,
                };
                // The texel variant's only storage binding is its output.
                let bindings = match &texel {
                    Some(t) => vec![dst.buf.binding(), t.clone()],
                    None => vec![src.buf.binding(), dst.buf.binding()],
                };
                rec.dispatch_named("mlp_fwd", &k, &bindings, &deps, &push, n as u64)?;
            }
        }
        Ok(())
    }

    /// Backward: deltas of every layer, `grads += dL/dW`, and `dx = dL/dinput` when given.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        grads: ParamSlice,
        io: (RowSlice, RowSlice, RowSlice),
        n: usize,
        bufs: &MlpTrainBuffers,
        dx: Option<RowSlice>,
    ) -> GpuResult<()> {
        let (input, output, dy) = io;
        self.check_params(&params)?;
        check_within_chunk(grads.array, grads.offset, self.config.n_params())?;
        need(bufs.acts, self.config.hidden_floats(n))?;
        need(bufs.deltas, self.config.delta_floats(n))?;
        need(bufs.scratch, self.wgrad_scratch_floats(n))?;
        if n == 0 {
            return Ok(());
        }
        let c = &self.config;
        let ctx = rec.context();
        let (nh, width) = (c.n_hidden_layers, c.width);
        let hidden_total = c.hidden_values(n);
        let out_cols = c.out_delta_cols();
        let out_deltas = RowSlice { buf: bufs.deltas, stride: out_cols, col: hidden_total };
        let hidden_deltas = |m: usize| RowSlice { buf: bufs.deltas, stride: width, col: m * n * width };
        let acts = |m: usize| RowSlice { buf: bufs.acts, stride: width, col: m * n * width };

        let spec = [
            ("N_OUT", c.n_output as u32),
            ("N_COLS", out_cols as u32),
            ("ACT", c.output_activation.code()),
            ("VEC_D", vec_width(&[out_cols, hidden_total])),
        ];
        let k = Kernel::with_spec(ctx, &shaders::MLP_OUT_DELTA, &spec)?;
        let push = OutDeltaPush {
            n: n as u32,
            y_stride: output.stride as u32,
            y_col: output.col as u32,
            dy_stride: dy.stride as u32,
            dy_col: dy.col as u32,
            d_stride: out_cols as u32,
            d_col: hidden_total as u32,
        };
        let bindings = [output.buf.binding(), dy.buf.binding(), bufs.deltas.binding()];
        rec.dispatch_named("mlp_out_delta", &k, &bindings, &[], &push, n as u64)?;

        // Through every matrix transposed, last to first: matrix m turns layer m's deltas into layer m-1's (masked
        // by the ReLU that produced its input), and matrix 0 gives dL/dinput.
        let base = weights_address(&params)?;
        let offsets = matrix_offsets(c);
        let deps = params.array.deps();
        let shapes = c.layer_shapes();
        for m in (0..=nh).rev() {
            let d_in = if m == nh { out_deltas } else { hidden_deltas(m) };
            let (d_w, in_w) = shapes[m];
            let (target, mask) = match (m, dx) {
                (0, Some(dx)) => (dx, None),
                (0, None) => break,
                _ => (hidden_deltas(m - 1), Some(acts(m - 1))),
            };
            let half_mask = c.half_activations && mask.is_some();
            if self.tiling.shared_tiles {
                let w_addr = base + 4 * offsets[m] as u64;
                let io = (d_in, target, (false, half_mask, false));
                self.tile_layer(rec, (w_addr, &deps), TileOp::Backward(mask), io, n, (d_w, in_w))?;
                continue;
            }
            let a = mask.unwrap_or(d_in);
            for b in blocks(in_w, self.tiling.mac_budget / d_w) {
                let mut spec = vec![
                    ("OUT_W", d_w as u32),
                    ("IN_W", in_w as u32),
                    ("KB", b.len() as u32),
                    ("MASK", u32::from(mask.is_some())),
                    ("VEC_OUT", vec_width(&[target.stride, target.col + b.start])),
                ];
                // The texel variant reads both row sets through views (with MASK = 0, the deltas' twice: its
                // activation slot is bound but not read).
                let texels = match self.texel_rows(d_in.buf, false, &[d_in.stride, d_in.col])? {
                    Some(d_tex) => {
                        self.texel_rows(a.buf, half_mask, &[a.stride, a.col + b.start])?.map(|a_tex| [d_tex, a_tex])
                    }
                    None => None,
                };
                if texels.is_none() {
                    spec.push(("VEC_D", vec_width(&[d_in.stride, d_in.col])));
                    let vec_a = if mask.is_some() { row_vec(half_mask, &[a.stride, a.col + b.start]) } else { 1 };
                    spec.push(("VEC_A", vec_a));
                    spec.push(("HALF_A", u32::from(half_mask)));
                }
                let blob = if texels.is_some() { &shaders::MLP_LAYER_BWD_TEXEL } else { &shaders::MLP_LAYER_BWD };
                self.texel_dispatches.fetch_add(usize::from(texels.is_some()), Ordering::Relaxed);
                let k = Kernel::with_spec(ctx, blob, &spec)?;
                let push = LayerBwdPush {
                    w_addr: base + 4 * (offsets[m] + b.start) as u64,
                    n: n as u32,
                    d_stride: d_in.stride as u32,
                    d_col: d_in.col as u32,
                    a_stride: a.stride as u32,
                    a_col: (a.col + b.start) as u32,
                    out_stride: target.stride as u32,
                    out_col: (target.col + b.start) as u32,
                    pad: 0,
                };
                let bindings = match texels {
                    Some([d_tex, a_tex]) => vec![target.buf.binding(), d_tex, a_tex],
                    None => vec![d_in.buf.binding(), a.buf.binding(), target.buf.binding()],
                };
                rec.dispatch_named("mlp_bwd", &k, &bindings, &deps, &push, n as u64)?;
            }
        }

        // Weight gradients, matrix by matrix: delta of its output x activation of its input. The last matrix's rows
        // past `out_cols` are padding, their gradient stays as it is (zero).
        let split_rows = rows_per_split(n, self.tiling.shared_tiles);
        let splits = n.div_ceil(split_rows).max(1);
        for (m, &(rows, in_w)) in c.matrices().iter().enumerate() {
            let out_w = if m == nh { out_cols } else { rows };
            let d = if m == nh { out_deltas } else { hidden_deltas(m) };
            let a = if m == 0 { input } else { acts(m - 1) };
            let half_a = c.half_activations && m > 0;
            self.wgrad_partials(rec, (d, a, half_a), (n, split_rows, splits), (out_w, in_w), bufs.scratch)?;
            let push = ReducePush {
                grads: grads.array.table_address()?,
                shift: grads.array.chunk_shift(),
                g_offset: (grads.offset + offsets[m]) as u32,
                count: (out_w * in_w) as u32,
                splits: splits as u32,
                pad: 0,
                pad2: 0,
            };
            let bindings = [bufs.scratch.binding()];
            rec.dispatch_named(
                "mlp_wgrad_reduce",
                &self.reduce,
                &bindings,
                &grads.array.deps(),
                &push,
                // one workgroup of 256 per 32 elements (the kernel's header)
                ((out_w * in_w).div_ceil(32) * 256) as u64,
            )?;
        }
        Ok(())
    }

    /// One layer's forward or backward product through `mlp_tile_layer` (or `mlp_coop_layer`): A rows into C rows
    /// (which of A, the mask and C hold fp16) with the weights at `w_addr` (in `deps`), `shape` is (k_dim, cols),
    /// the summed and the written widths.
    fn tile_layer(
        &self,
        rec: &mut Recorder,
        (w_addr, deps): (u64, &[ash::vk::Buffer]),
        op: TileOp,
        (a, out, (half_a, half_m, half_c)): (RowSlice, RowSlice, (bool, bool, bool)),
        n: usize,
        shape: (usize, usize),
    ) -> GpuResult<()> {
        let (k_dim, cols) = shape;
        let bn = tile_columns(cols);
        // Forward: W(t, c) = W[c][t] over the layer's k_dim inputs; backward: W(t, c) = W[t][c], cols inputs.
        let (epi, act, mask, label, (ws_t, ws_c)) = match op {
            TileOp::Forward(act) => (0, act.code(), None, "mlp_fwd", (1, k_dim)),
            TileOp::Backward(Some(m)) => (1, 0, Some(m), "mlp_bwd", (cols, 1)),
            TileOp::Backward(None) => (2, 0, None, "mlp_bwd", (cols, 1)),
        };
        let spec = [
            ("BN", bn as u32),
            ("EPI", epi),
            ("ACT", act),
            ("HALF_A", half_a.into()),
            ("HALF_M", half_m.into()),
            ("HALF_C", half_c.into()),
        ];
        let (k, rows_per_tile, threads) = match (self.tiling.coop_layers, &shaders::MLP_COOP_LAYER) {
            (true, Some(blob)) => (Kernel::with_spec(rec.context(), blob, &spec)?, COOP_ROWS, COOP_THREADS),
            _ => (Kernel::with_spec(rec.context(), &shaders::MLP_TILE_LAYER, &spec)?, 4096 / bn, TILE_THREADS),
        };
        let m = mask.unwrap_or(a);
        let col_tiles = cols.div_ceil(bn);
        let push = TileLayerPush {
            w_addr,
            n: n as u32,
            k_dim: k_dim as u32,
            cols: cols as u32,
            ws_t: ws_t as u32,
            ws_c: ws_c as u32,
            a_stride: a.stride as u32,
            a_col: a.col as u32,
            m_stride: m.stride as u32,
            m_col: m.col as u32,
            c_stride: out.stride as u32,
            c_col: out.col as u32,
            col_tiles: col_tiles as u32,
        };
        let groups = n.div_ceil(rows_per_tile) * col_tiles;
        let bindings = [a.buf.binding(), m.buf.binding(), out.buf.binding()];
        rec.dispatch_named(label, &k, &bindings, deps, &push, groups as u64 * threads)
    }

    /// One matrix's split-K weight-gradient partials into `scratch`: `n` rows in `splits` splits of `split_rows`,
    /// for an `out_w` x `in_w` matrix, through `mlp_tile_wgrad` (shared-memory tiles: 256 threads per tile and
    /// split) or `mlp_wgrad` (register tiles: one invocation per tile and split).
    fn wgrad_partials(
        &self,
        rec: &mut Recorder,
        (d, a, half_a): (RowSlice, RowSlice, bool),
        (n, split_rows, splits): (usize, usize, usize),
        (out_w, in_w): (usize, usize),
        scratch: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let ctx = rec.context();
        let (k, tiles_j, tiles_k, threads) =
            if let (true, Some(blob)) = (self.tiling.coop_matrix, &shaders::MLP_COOP_WGRAD) {
                let tj = tile_columns(out_w);
                let tk = tile_columns(in_w);
                debug_assert!(tj <= 64 && tk <= 64, "mlp_coop_wgrad stages tiles of at most 64 x 64");
                let spec = [("TJ", tj as u32), ("TK", tk as u32), ("HALF_A", half_a.into())];
                (Kernel::with_spec(ctx, blob, &spec)?, out_w.div_ceil(tj), in_w.div_ceil(tk), COOP_THREADS)
            } else if self.tiling.shared_tiles {
                let tj = tile_columns(out_w);
                let tk = (4096 / tj).min(in_w.next_power_of_two().clamp(16, 256));
                let spec = [("TJ", tj as u32), ("TK", tk as u32), ("HALF_A", half_a.into())];
                let k = Kernel::with_spec(ctx, &shaders::MLP_TILE_WGRAD, &spec)?;
                (k, out_w.div_ceil(tj), in_w.div_ceil(tk), TILE_THREADS)
            } else {
                let (jt, kt) = register_wgrad_tile(&self.tiling, (out_w, in_w), splits);
                let spec = [
                    ("JT", jt as u32),
                    ("KT", kt as u32),
                    ("VEC_D", vec_width(&[d.stride, d.col, jt])),
                    ("VEC_A", row_vec(half_a, &[a.stride, a.col, kt])),
                    ("VEC_P", vec_width(&[in_w, kt])),
                    ("ROWS", self.tiling.wgrad_rows as u32),
                    ("HALF_A", half_a.into()),
                ];
                (Kernel::with_spec(ctx, &shaders::MLP_WGRAD, &spec)?, out_w / jt, in_w / kt, 1)
            };
        let push = WgradPush::new((d, a), (n, split_rows, splits), (out_w, in_w), tiles_k);
        let work = (tiles_j * tiles_k * splits) as u64 * threads;
        let bindings = [d.buf.binding(), a.buf.binding(), scratch.binding()];
        rec.dispatch_named("mlp_wgrad", &k, &bindings, &[], &push, work)
    }
}

/// Invocations of `mlp_wgrad` below which its tile shrinks: 4 workgroups of 64, so that a short batch still
/// spreads over the host's threads (lavapipe runs a workgroup on one thread; at 12,288 rows a 64 x 64 matrix in one
/// 64 x 64 tile was 48 invocations, one workgroup, and its weight gradient took 16-18 ms against 13-15 with the
/// old 32 x 32 tiles).
const WGRAD_MIN_INVOCATIONS: usize = 256;

/// `mlp_wgrad`'s tile (rows, columns of the matrix) for an `out_w` x `in_w` matrix in `splits` splits: the
/// tiling's sizes (the largest power-of-two divisors of the matrix's sides up to them, at least 4), halved (the
/// longer side, columns first: taller tiles measured faster) while the dispatch would have fewer than
/// [`WGRAD_MIN_INVOCATIONS`] invocations, down to 4 x 4. Both sides stay multiples of 4 (every MLP width is a
/// multiple of 16), which fp16 rows need.
fn register_wgrad_tile(t: &MlpTiling, (out_w, in_w): (usize, usize), splits: usize) -> (usize, usize) {
    let pow2 = |m: usize| 1usize << (usize::BITS - 1 - m.max(4).leading_zeros());
    let (mut jt, mut kt) = (tile(out_w, pow2(t.wgrad_tile_j)), tile(in_w, pow2(t.wgrad_tile_k)));
    while (out_w / jt) * (in_w / kt) * splits < WGRAD_MIN_INVOCATIONS && jt.max(kt) > 4 {
        if kt >= jt {
            kt /= 2;
        } else {
            jt /= 2;
        }
    }
    (jt, kt)
}

/// Access width of a row run for `row_io.glsl`: [`vec_width`] for floats; for fp16 rows the widest of 16, 8, 4
/// halves dividing every offset, else 2 (fp16 rows are only hidden activations, whose widths and blocks are even).
fn row_vec(half: bool, offsets: &[usize]) -> u32 {
    if half {
        debug_assert!(offsets.iter().all(|o| o % 2 == 0), "fp16 rows at odd offsets {offsets:?}");
        [16usize, 8, 4].into_iter().find(|v| offsets.iter().all(|o| o % v == 0)).unwrap_or(2) as u32
    } else {
        vec_width(offsets)
    }
}

/// The rows of `s` from row `start` on.
fn rows_from(s: RowSlice<'_>, start: usize) -> RowSlice<'_> {
    RowSlice { col: s.col + start * s.stride, ..s }
}

/// Offset of every matrix in the module's weights.
fn matrix_offsets(c: &MlpConfig) -> Vec<usize> {
    c.matrices()
        .iter()
        .scan(0, |off, (r, cols)| {
            let at = *off;
            *off += r * cols;
            Some(at)
        })
        .collect()
}

/// Device address of the module's first weight (the module lies inside one chunk: `check_within_chunk`).
fn weights_address(p: &ParamSlice) -> GpuResult<u64> {
    let shift = p.array.chunk_shift();
    let chunk = &p.array.chunks()[p.offset >> shift];
    Ok(chunk.device_address()? + 4 * (p.offset & ((1usize << shift) - 1)) as u64)
}

fn need(buf: &GpuBuffer<f32>, floats: usize) -> GpuResult<()> {
    if buf.len() < floats {
        return Err(GpuError::Buffer {
            name: buf.name().into(),
            msg: format!("needs {floats} floats, has {}", buf.len()),
        });
    }
    Ok(())
}

/// Kernels address a module's weights through one chunk: the range may not cross a chunk boundary.
fn check_within_chunk(a: &LargeArray<f32>, offset: usize, len: usize) -> GpuResult<()> {
    let chunk = 1usize << a.chunk_shift();
    if offset + len > a.len() || (len > 0 && offset / chunk != (offset + len - 1) / chunk) {
        return Err(GpuError::Buffer {
            name: a.name().into(),
            msg: format!("{len} floats at {offset} run past the array or across a chunk boundary"),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{blocks, tile, MlpTiling};
    use crate::nn::vec_width;

    #[test]
    fn blocks_cover_the_outputs_in_near_equal_multiples_of_four() {
        let one = |total: usize| std::iter::once(0..total).collect::<Vec<_>>();
        assert_eq!(blocks(64, 128), one(64));
        assert_eq!(blocks(6, 4096 / 64), one(6));
        assert_eq!(blocks(128, 4096 / 128), vec![0..32, 32..64, 64..96, 96..128]);
        assert_eq!(blocks(128, 4096 / 80), vec![0..44, 44..88, 88..128]);
        assert_eq!(blocks(16, 2), vec![0..4, 4..8, 8..12, 12..16]);
        for (total, max) in [(100, 30), (7, 4), (128, 51), (33, 8)] {
            let b = blocks(total, max);
            assert_eq!(b.first().map(|r| r.start), Some(0));
            assert_eq!(b.last().map(|r| r.end), Some(total));
            assert!(b.windows(2).all(|w| w[0].end == w[1].start && w[0].len() % 4 == 0));
            assert!(b.iter().all(|r| r.len() <= (max / 4 * 4).max(4)), "{total} {max}: {b:?}");
        }
    }

    #[test]
    fn tiling_overrides_name_the_bad_key() {
        let t = MlpTiling {
            shared_tiles: false,
            mac_budget: 4096,
            wgrad_tile_j: 32,
            wgrad_tile_k: 32,
            wgrad_rows: 4,
            coop_matrix: false,
            coop_layers: false,
            texel_rows: true,
        };
        let o = t.with_overrides("mac_budget=8192, wgrad_rows=8,shared=1,wgrad_tile_j=64").expect("valid");
        let want = MlpTiling {
            shared_tiles: true,
            mac_budget: 8192,
            wgrad_tile_j: 64,
            wgrad_tile_k: 32,
            wgrad_rows: 8,
            coop_matrix: false,
            coop_layers: false,
            texel_rows: true,
        };
        assert_eq!(o, want);
        assert!(!t.with_overrides("texel=0").expect("valid").texel_rows);
        assert!(t.with_overrides("texel=2").unwrap_err().to_string().contains("texel"));
        let both = t.with_overrides("wgrad_tile=16").expect("valid");
        assert_eq!((both.wgrad_tile_j, both.wgrad_tile_k), (16, 16));
        assert!(t.with_overrides("shared=2").unwrap_err().to_string().contains("shared"));
        assert_eq!(t.with_overrides("tile=3").unwrap_err().key, "tile");
        assert!(t.with_overrides("wgrad_tile=x").unwrap_err().to_string().contains("wgrad_tile"));
        assert!(t.with_overrides("wgrad_rows=0").unwrap_err().to_string().contains("wgrad_rows"));
        assert!(t.with_overrides("mac_budget").unwrap_err().to_string().contains("key=value"));
    }

    #[test]
    fn tiling_overrides_carry_the_tensor_core_switches_along() {
        let gpu = MlpTiling { coop_matrix: true, coop_layers: true, ..MlpTiling::GPU_DEFAULTS };
        let off = |t: MlpTiling| (t.shared_tiles, t.coop_matrix, t.coop_layers);
        // The register tiles have no tensor-core variant: shared=0 alone turns them off too.
        assert_eq!(off(gpu.with_overrides("shared=0").expect("valid")), (false, false, false));
        assert_eq!(off(gpu.with_overrides("coop=0").expect("valid")), (true, false, false));
        assert_eq!(off(gpu.with_overrides("coop_layers=0").expect("valid")), (true, true, false));
        // Explicit keys are kept as asked (Mlp::with_tiling then refuses what cannot run).
        assert_eq!(off(gpu.with_overrides("shared=0,coop=1").expect("valid")), (false, true, true));
        assert_eq!(off(gpu.with_overrides("coop=0,coop_layers=1").expect("valid")), (true, false, true));
        assert!(gpu.with_overrides("coop_layers=2").unwrap_err().to_string().contains("coop_layers"));
    }

    #[test]
    fn register_wgrad_tiles_shrink_for_short_batches_and_stay_multiples_of_4() {
        use super::{register_wgrad_tile, WGRAD_MIN_INVOCATIONS};
        let t = MlpTiling::CPU_DEFAULTS;
        // 65,536 rows: 256 splits, the full tile.
        assert_eq!(register_wgrad_tile(&t, (128, 128), 256), (64, 64));
        assert_eq!(register_wgrad_tile(&t, (8, 80), 256), (8, 16));
        // 12,288 rows (48 splits) of a 64 x 64 matrix: halved until 256 invocations.
        let (jt, kt) = register_wgrad_tile(&t, (64, 64), 48);
        assert_eq!((jt, kt), (32, 16));
        assert!((64 / jt) * (64 / kt) * 48 >= WGRAD_MIN_INVOCATIONS);
        // A tiny batch stops at 4 x 4; an override of 1 or 3 still gives multiples of 4.
        assert_eq!(register_wgrad_tile(&t, (16, 16), 1), (4, 4));
        let odd = MlpTiling { wgrad_tile_j: 3, wgrad_tile_k: 5, ..t };
        let (jt, kt) = register_wgrad_tile(&odd, (32, 48), 1000);
        assert!(jt % 4 == 0 && kt % 4 == 0, "{jt} x {kt}");
    }

    #[test]
    fn shared_tile_splits_stay_within_the_cap_and_the_scratch() {
        use super::{rows_per_split, MAX_TILE_SPLITS, ROWS_PER_SPLIT};
        for n in [1, 255, 256, 1003, 65_536, 65_537, 70_001, 1 << 20, 3_000_017] {
            let r = rows_per_split(n, true);
            assert!(r % 16 == 0 && r >= ROWS_PER_SPLIT, "{n}: {r}");
            assert!(n.div_ceil(r) <= MAX_TILE_SPLITS, "{n}: {} splits", n.div_ceil(r));
            assert!(n.div_ceil(r) <= n.div_ceil(ROWS_PER_SPLIT).max(1), "{n}: more splits than the scratch holds");
            assert_eq!(rows_per_split(n, false), ROWS_PER_SPLIT);
        }
    }

    #[test]
    fn gradient_tiles_divide_the_matrix() {
        assert_eq!(tile(80, 32), 16);
        assert_eq!(tile(128, 32), 32);
        assert_eq!(tile(16, 32), 16);
        assert_eq!(tile(48, 4), 4);
    }

    #[test]
    fn access_width_divides_every_offset() {
        assert_eq!(vec_width(&[64, 0]), 8);
        assert_eq!(vec_width(&[6, 0]), 2);
        assert_eq!(vec_width(&[35, 2]), 1);
        assert_eq!(vec_width(&[16, 4, 32]), 4);
    }
}
