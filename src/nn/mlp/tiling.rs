//! Which MLP kernels run on a device and their block sizes ([`MlpTiling`]: the device's defaults, then
//! `MSNERF_MLP_TILING`'s overrides), and the block arithmetic the dispatches share (weight-gradient splits, output
//! blocks, tile sides).

use super::*;

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
pub(super) fn rows_per_split(n: usize, shared_tiles: bool) -> usize {
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
pub(super) fn blocks(total: usize, max: usize) -> Vec<Range<usize>> {
    let max = (max / 4 * 4).max(4);
    let size = if total <= max { total } else { total.div_ceil(total.div_ceil(max)).next_multiple_of(4) };
    (0..total).step_by(size.max(1)).map(|s| s..(s + size).min(total)).collect()
}

/// The largest of `max`, `max / 2`, ... (at least 1) that divides `total`.
pub(super) fn tile(total: usize, max: usize) -> usize {
    let mut t = max.max(1);
    while total % t != 0 {
        t /= 2;
    }
    t
}

/// Invocations of `mlp_wgrad` below which its tile shrinks: 4 workgroups of 64, so that a short batch still
/// spreads over the host's threads (lavapipe runs a workgroup on one thread; at 12,288 rows a 64 x 64 matrix in one
/// 64 x 64 tile was 48 invocations, one workgroup, and its weight gradient took 16-18 ms against 13-15 with the
/// old 32 x 32 tiles).
pub(super) const WGRAD_MIN_INVOCATIONS: usize = 256;

/// `mlp_wgrad`'s tile (rows, columns of the matrix) for an `out_w` x `in_w` matrix in `splits` splits: the
/// tiling's sizes (the largest power-of-two divisors of the matrix's sides up to them, at least 4), halved (the
/// longer side, columns first: taller tiles measured faster) while the dispatch would have fewer than
/// [`WGRAD_MIN_INVOCATIONS`] invocations, down to 4 x 4. Both sides stay multiples of 4 (every MLP width is a
/// multiple of 16), which fp16 rows need.
pub(super) fn register_wgrad_tile(t: &MlpTiling, (out_w, in_w): (usize, usize), splits: usize) -> (usize, usize) {
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
