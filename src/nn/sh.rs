//! Spherical-harmonics direction encoding, degree 4 (16 values) in tiny-cuda-nn's convention (nerfacto.md §2.16),
//! on unit directions. Kernels `sh_fwd` and `sh_bwd` (`glsl/encoding/`); CPU twin [`crate::reference::sh`].
//!
//! - `sh_fwd`: bindings 0 dirs (f32[3n], read), 1 out (f32, written); push `{n, row_stride, col}`; one invocation
//!   per direction, 64 per group. Writes `out[i * row_stride + col + k]`, k < 16, and nothing else, so the
//!   encoding can fill columns of a wider MLP input row.
//! - `sh_bwd`: bindings 0 dirs, 1 d_sh (rows as in the forward, read), 2 d_dirs (f32[3n], written or
//!   accumulated); push `{n, row_stride, col, accumulate}`. The gradient is that of the polynomials (x, y, z
//!   independent, not projected onto the sphere).

use crate::gpu::{GpuBuffer, GpuError, GpuResult, Kernel, Recorder};
use crate::shaders;

/// Values per direction.
pub const SH_DIM: usize = 16;

/// Where the 16 values of direction i live in a row-major matrix: `row_stride * i + col + k`.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct RowLayout {
    /// Elements per row (at least `col + 16`).
    pub row_stride: usize,
    /// First column of the SH values.
    pub col: usize,
}

impl RowLayout {
    /// Rows holding only the 16 SH values.
    pub const DENSE: RowLayout = RowLayout { row_stride: SH_DIM, col: 0 };

    fn check(&self, what: &str, buf_len: usize, n: usize) -> GpuResult<()> {
        let need = if n == 0 { 0 } else { (n - 1) * self.row_stride + self.col + SH_DIM };
        if self.col + SH_DIM > self.row_stride || need > buf_len || need > u32::MAX as usize {
            return Err(GpuError::Buffer {
                name: what.into(),
                msg: format!(
                    "{n} SH rows (stride {}, column {}) need {need} elements, the buffer has {buf_len}",
                    self.row_stride, self.col
                ),
            });
        }
        Ok(())
    }
}

crate::push_constants! {
    struct FwdPush {
        n: u32,
        row_stride: u32,
        col: u32,
    }
}

crate::push_constants! {
    struct BwdPush {
        n: u32,
        row_stride: u32,
        col: u32,
        accumulate: u32,
    }
}

fn check_dirs(dirs: &GpuBuffer<f32>, n: usize) -> GpuResult<()> {
    if 3 * n > dirs.len() {
        return Err(GpuError::Buffer {
            name: dirs.name().into(),
            msg: format!("{n} directions need {} floats, the buffer has {}", 3 * n, dirs.len()),
        });
    }
    Ok(())
}

/// Records the encoding of the first `n` directions of `dirs` (3 floats each) into `out` at `layout`.
pub fn sh_fwd(
    rec: &mut Recorder,
    dirs: &GpuBuffer<f32>,
    n: usize,
    out: &GpuBuffer<f32>,
    layout: RowLayout,
) -> GpuResult<()> {
    check_dirs(dirs, n)?;
    layout.check(out.name(), out.len(), n)?;
    let k = Kernel::<FwdPush>::new(rec.context(), &shaders::SH_FWD)?;
    let push = FwdPush { n: n as u32, row_stride: layout.row_stride as u32, col: layout.col as u32 };
    rec.dispatch(&k, &[dirs.binding(), out.binding()], &push, n as u64)
}

/// Records `d_dirs = dL/d(dirs)` (or `d_dirs += ...` when `accumulate`) from `d_sh = dL/d(SH)` at `layout`.
pub fn sh_bwd(
    rec: &mut Recorder,
    dirs: &GpuBuffer<f32>,
    n: usize,
    d_sh: &GpuBuffer<f32>,
    layout: RowLayout,
    d_dirs: &GpuBuffer<f32>,
    accumulate: bool,
) -> GpuResult<()> {
    check_dirs(dirs, n)?;
    check_dirs(d_dirs, n)?;
    layout.check(d_sh.name(), d_sh.len(), n)?;
    let k = Kernel::<BwdPush>::new(rec.context(), &shaders::SH_BWD)?;
    let push = BwdPush {
        n: n as u32,
        row_stride: layout.row_stride as u32,
        col: layout.col as u32,
        accumulate: u32::from(accumulate),
    };
    rec.dispatch(&k, &[dirs.binding(), d_sh.binding(), d_dirs.binding()], &push, n as u64)
}

#[cfg(test)]
mod sh_dim_tests {
    /// The GLSL kernels' `SH_DIM` (glsl/encoding/sh_constants.glsl) is this module's.
    #[test]
    fn glsl_sh_dim_is_the_rust_constant() {
        let text = include_str!("../../glsl/encoding/sh_constants.glsl");
        let line = text.lines().find(|l| l.starts_with("const uint SH_DIM")).expect("SH_DIM declared");
        let value: usize = line
            .split('=')
            .nth(1)
            .expect("= value")
            .trim()
            .trim_end_matches(';')
            .trim_end_matches('u')
            .parse()
            .expect("a number");
        assert_eq!(value, super::SH_DIM);
    }
}
