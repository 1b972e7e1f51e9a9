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

mod config;
mod tiling;

pub use config::*;
pub use tiling::*;

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
