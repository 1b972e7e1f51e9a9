//! `record_check_finite`: sets a flag when a float buffer holds a NaN or Inf (kernel `check_finite`; twin
//! [`crate::reference::util::any_non_finite`]). The training step's NaN/Inf guard runs it over every gradient chunk,
//! each loss buffer and, gated on the result, its named intermediate buffers ([`record_check_finite_slot`]).

use crate::gpu::{GpuBuffer, GpuError, GpuResult, Kernel, Recorder};
use crate::shaders;

crate::push_constants! {
    struct CheckPush {
        n: u32,
        stride: u32,
        slot: u32,
    }
}

/// Elements each invocation reads (the dispatch has n / this many invocations, at least one group).
const PER_INVOCATION: usize = 64;

/// Records `flag[0] = 1` if `data[0..n]` holds a NaN or Inf; leaves the flag alone otherwise (zero it first).
pub fn record_check_finite(
    rec: &mut Recorder,
    data: &GpuBuffer<f32>,
    n: usize,
    flag: &GpuBuffer<u32>,
) -> GpuResult<()> {
    record_check_finite_slot(rec, data, n, flag, 0, false)
}

/// Records `flags[0] = flags[slot] = 1` if `data[0..n]` holds a NaN or Inf. `gated`: only if `flags[0]` is
/// already set when the kernel runs (the check is skipped, in a few microseconds, on a clean step).
pub fn record_check_finite_slot(
    rec: &mut Recorder,
    data: &GpuBuffer<f32>,
    n: usize,
    flag: &GpuBuffer<u32>,
    slot: usize,
    gated: bool,
) -> GpuResult<()> {
    if n > data.len() || n > u32::MAX as usize || slot >= flag.len() {
        return Err(GpuError::Buffer {
            name: data.name().into(),
            msg: format!("check_finite over {n} of {} elements into flag {slot} of {}", data.len(), flag.len()),
        });
    }
    if n == 0 {
        return Ok(());
    }
    let k = Kernel::<CheckPush>::with_spec(rec.context(), &shaders::CHECK_FINITE, &[("GATED", u32::from(gated))])?;
    let stride = n.div_ceil(PER_INVOCATION).max(1);
    rec.dispatch(
        &k,
        &[data.binding(), flag.binding()],
        &CheckPush { n: n as u32, stride: stride as u32, slot: slot as u32 },
        stride as u64,
    )
}
