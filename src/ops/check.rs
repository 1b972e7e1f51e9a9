//! `record_check_finite`: sets a flag when a float buffer holds a NaN or Inf (kernel `check_finite`; twin
//! [`crate::reference::util::any_non_finite`]). The training step's NaN/Inf guard runs it over every gradient chunk.

use crate::gpu::{GpuBuffer, GpuError, GpuResult, Kernel, Recorder};
use crate::shaders;

crate::push_constants! {
    struct CheckPush {
        n: u32,
        stride: u32,
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
    if n > data.len() || n > u32::MAX as usize || flag.is_empty() {
        return Err(GpuError::Buffer {
            name: data.name().into(),
            msg: format!("check_finite over {n} of {} elements into a flag of {}", data.len(), flag.len()),
        });
    }
    if n == 0 {
        return Ok(());
    }
    let k = Kernel::<CheckPush>::new(rec.context(), &shaders::CHECK_FINITE)?;
    let stride = n.div_ceil(PER_INVOCATION).max(1);
    rec.dispatch(
        &k,
        &[data.binding(), flag.binding()],
        &CheckPush { n: n as u32, stride: stride as u32 },
        stride as u64,
    )
}
