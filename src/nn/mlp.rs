//! Fully fused MLP (tiny-cuda-nn `FullyFusedMLP` semantics, spec/nerfacto.md §4): no biases, ReLU hidden layers of
//! width 16/32/64/128, any input width (padded to 16 by the caller's row layout), any output width (padded to 16),
//! output activation none / sigmoid / exponential / ReLU. Weights: row-major matrices W_in (WIDTH x in_pad),
//! N_HIDDEN-1 hidden (WIDTH x WIDTH), W_out (out_pad x WIDTH), contiguous, inside one chunk of a parameter array.
//!
//! Kernels: `mlp_fwd` (training variant stores hidden activations; inference keeps nothing), `mlp_bwd` (deltas of
//! every layer and the input gradient), `mlp_wgrad` + `mlp_wgrad_reduce` (weight gradients, split over the batch and
//! summed in a fixed order: deterministic). Rows per invocation come from the device: several on CPU devices
//! (lavapipe's SIMD runs 8 invocations at once, so each weight load feeds ROWS x 8 FMAs), one on GPUs.

use super::{ParamSlice, RowSlice};
use crate::gpu::{Context, GpuBuffer, GpuError, GpuResult, Kernel, LargeArray, Recorder};
use crate::shaders;
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

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
}

impl MlpConfig {
    pub fn validate(&self) -> Result<(), String> {
        if ![16, 32, 64, 128].contains(&self.width) {
            return Err(format!("MLP width must be 16, 32, 64 or 128, got {}", self.width));
        }
        if self.n_hidden_layers == 0 || self.n_hidden_layers > 8 {
            return Err(format!("n_hidden_layers must be 1..=8, got {}", self.n_hidden_layers));
        }
        if self.n_input == 0 || self.n_input > 256 || self.n_output == 0 || self.n_output > 256 {
            return Err(format!("MLP input/output widths must be 1..=256, got {} and {}", self.n_input, self.n_output));
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

    /// Floats of stored hidden activations (and of hidden deltas) for `n` rows.
    pub fn hidden_floats(&self, n: usize) -> usize {
        self.n_hidden_layers * n * self.width
    }

    /// Floats of the deltas buffer for `n` rows: hidden deltas, then output deltas.
    pub fn delta_floats(&self, n: usize) -> usize {
        self.hidden_floats(n) + n * self.out_pad()
    }

    /// Floats of the split-K scratch of the weight gradients for `n` rows.
    pub fn wgrad_scratch_floats(&self, n: usize) -> usize {
        let splits = n.div_ceil(ROWS_PER_SPLIT).max(1);
        splits * self.matrices().iter().map(|(r, c)| r * c).max().unwrap_or(0)
    }

    /// Multiply-adds per row of a forward pass (x2 for FLOPs; the backward costs twice the forward).
    pub fn macs_per_row(&self) -> usize {
        self.n_params()
    }
}

#[repr(C)]
#[derive(Copy, Clone, Pod, Zeroable)]
struct FwdPush {
    params: u64,
    shift: u32,
    w_offset: u32,
    n: u32,
    in_stride: u32,
    in_col: u32,
    out_stride: u32,
    out_col: u32,
    n_out: u32,
}

#[repr(C)]
#[derive(Copy, Clone, Pod, Zeroable)]
struct BwdPush {
    params: u64,
    shift: u32,
    w_offset: u32,
    n: u32,
    y_stride: u32,
    y_col: u32,
    dy_stride: u32,
    dy_col: u32,
    n_out: u32,
    dx_stride: u32,
    dx_col: u32,
    want_dx: u32,
    pad: u32,
}

#[repr(C)]
#[derive(Copy, Clone, Pod, Zeroable)]
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
}

#[repr(C)]
#[derive(Copy, Clone, Pod, Zeroable)]
struct ReducePush {
    grads: u64,
    shift: u32,
    g_offset: u32,
    count: u32,
    splits: u32,
    pad: u32,
    pad2: u32,
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
    rows: u32,
    fwd_train: Kernel<FwdPush>,
    fwd_infer: Kernel<FwdPush>,
    bwd: Kernel<BwdPush>,
    wgrad: Kernel<WgradPush>,
    reduce: Kernel<ReducePush>,
}

/// Rows per split of the weight-gradient reduction.
pub const ROWS_PER_SPLIT: usize = 256;

impl Mlp {
    pub fn new(ctx: &Context, config: &MlpConfig) -> GpuResult<Self> {
        config.validate().map_err(|msg| GpuError::Buffer { name: "MLP config".into(), msg })?;
        let rows = if ctx.caps().is_cpu { 4 } else { 1 };
        Self::with_rows(ctx, config, rows)
    }

    /// With an explicit number of rows per invocation (benchmarks compare them).
    pub fn with_rows(ctx: &Context, config: &MlpConfig, rows: u32) -> GpuResult<Self> {
        let c = config;
        let spec = |store: u32| {
            vec![
                (0, c.width as u32),
                (1, c.in_pad() as u32),
                (2, c.out_pad() as u32),
                (3, c.n_hidden_layers as u32),
                (4, c.output_activation.code()),
                (5, rows),
                (6, store),
            ]
        };
        Ok(Self {
            config: config.clone(),
            rows,
            fwd_train: Kernel::with_spec(ctx, &shaders::MLP_FWD, &spec(1))?,
            fwd_infer: Kernel::with_spec(ctx, &shaders::MLP_FWD, &spec(0))?,
            bwd: Kernel::with_spec(ctx, &shaders::MLP_BWD, &spec(0)[..6])?,
            wgrad: Kernel::new(ctx, &shaders::MLP_WGRAD)?,
            reduce: Kernel::new(ctx, &shaders::MLP_WGRAD_REDUCE)?,
        })
    }

    /// Floats of the split-K scratch for `n` rows.
    pub fn wgrad_scratch_floats(&self, n: usize) -> usize {
        self.config.wgrad_scratch_floats(n)
    }

    fn check_params(&self, p: &ParamSlice) -> GpuResult<()> {
        check_within_chunk(p.array, p.offset, self.config.n_params())
    }

    fn fwd_push(&self, params: &ParamSlice, input: &RowSlice, n: usize, output: &RowSlice) -> GpuResult<FwdPush> {
        self.check_params(params)?;
        Ok(FwdPush {
            params: params.array.table_address()?,
            shift: params.array.chunk_shift(),
            w_offset: params.offset as u32,
            n: n as u32,
            in_stride: input.stride as u32,
            in_col: input.col as u32,
            out_stride: output.stride as u32,
            out_col: output.col as u32,
            n_out: self.config.n_output as u32,
        })
    }

    /// Inference: output rows from input rows (`in_pad` columns read, `n_output` written); stores nothing.
    pub fn infer(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        input: RowSlice,
        n: usize,
        output: RowSlice,
    ) -> GpuResult<()> {
        let push = self.fwd_push(&params, &input, n, &output)?;
        // The acts binding is unused by the inference variant; bind the output to satisfy the layout.
        let bindings = [input.buf.binding(), output.buf.binding(), output.buf.binding()];
        let groups = (n as u64).div_ceil(self.rows as u64);
        rec.dispatch_named("mlp_infer", &self.fwd_infer, &bindings, &params.array.deps(), &push, groups)
    }

    /// Training forward: like `infer`, and stores the hidden activations in `acts`.
    pub fn forward(
        &self,
        rec: &mut Recorder,
        params: ParamSlice,
        input: RowSlice,
        n: usize,
        output: RowSlice,
        acts: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let push = self.fwd_push(&params, &input, n, &output)?;
        need(acts, self.config.hidden_floats(n))?;
        let bindings = [input.buf.binding(), output.buf.binding(), acts.binding()];
        let groups = (n as u64).div_ceil(self.rows as u64);
        rec.dispatch_named("mlp_fwd", &self.fwd_train, &bindings, &params.array.deps(), &push, groups)
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
        need(bufs.deltas, self.config.delta_floats(n))?;
        need(bufs.scratch, self.wgrad_scratch_floats(n))?;
        let c = &self.config;
        let dxs = dx.unwrap_or(RowSlice { buf: bufs.deltas, stride: 0, col: 0 });
        let push = BwdPush {
            params: params.array.table_address()?,
            shift: params.array.chunk_shift(),
            w_offset: params.offset as u32,
            n: n as u32,
            y_stride: output.stride as u32,
            y_col: output.col as u32,
            dy_stride: dy.stride as u32,
            dy_col: dy.col as u32,
            n_out: c.n_output as u32,
            dx_stride: dxs.stride as u32,
            dx_col: dxs.col as u32,
            want_dx: u32::from(dx.is_some()),
            pad: 0,
        };
        let bindings =
            [output.buf.binding(), dy.buf.binding(), bufs.acts.binding(), bufs.deltas.binding(), dxs.buf.binding()];
        let groups = (n as u64).div_ceil(self.rows as u64);
        rec.dispatch_named("mlp_bwd", &self.bwd, &bindings, &params.array.deps(), &push, groups)?;

        // Weight gradients, matrix by matrix: delta of its output x activation of its input.
        let splits = n.div_ceil(ROWS_PER_SPLIT).max(1);
        let mut g_offset = grads.offset;
        let hidden = c.hidden_floats(n);
        for (m, &(out_w, in_w)) in c.matrices().iter().enumerate() {
            let (d_buf_col, d_stride) =
                if m == c.n_hidden_layers { (hidden, c.out_pad()) } else { (m * n * c.width, c.width) };
            let (a_buf, a_stride, a_col) =
                if m == 0 { (input.buf, input.stride, input.col) } else { (bufs.acts, c.width, (m - 1) * n * c.width) };
            let push = WgradPush {
                n: n as u32,
                out_w: out_w as u32,
                in_w: in_w as u32,
                d_stride: d_stride as u32,
                d_col: d_buf_col as u32,
                a_stride: a_stride as u32,
                a_col: a_col as u32,
                rows_per_split: ROWS_PER_SPLIT as u32,
                splits: splits as u32,
            };
            let bindings = [bufs.deltas.binding(), a_buf.binding(), bufs.scratch.binding()];
            let work = (splits * (out_w / 4) * (in_w / 4)) as u64;
            rec.dispatch_named("mlp_wgrad", &self.wgrad, &bindings, &[], &push, work)?;
            let push = ReducePush {
                grads: grads.array.table_address()?,
                shift: grads.array.chunk_shift(),
                g_offset: g_offset as u32,
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
                (out_w * in_w) as u64,
            )?;
            g_offset += out_w * in_w;
        }
        Ok(())
    }
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
