//! Sum reduction: repeated `reduce_sum` passes (256 to 1 per group) until one value is left.

use super::{ScanValue, BLOCK};
use crate::gpu::{Binding, BufferDesc, Context, GpuBuffer, GpuResult, Kernel, MemoryCategory, Recorder};

crate::push_constants! {
    struct ReducePush {
        n: u32,
    }
}

/// Records `out[0] = sum(input[0..n])`. Temporaries live until the recorder's work completes.
pub fn reduce_sum<V: ScanValue>(
    rec: &mut Recorder,
    input: &GpuBuffer<V>,
    n: usize,
    out: &GpuBuffer<V>,
) -> GpuResult<()> {
    if n == 0 {
        return super::fill(rec, out, V::default(), 0, 1);
    }
    let ctx = rec.context();
    let k = Kernel::<ReducePush>::new(ctx, V::REDUCE)?;
    let mut cur: Binding = input.binding();
    let mut cur_n = n;
    for groups in partial_lens(n) {
        let partial = GpuBuffer::<V>::new(
            ctx,
            &BufferDesc { name: "reduce partials", len: groups, category: MemoryCategory::Other },
        )?;
        rec.dispatch(&k, &[cur, partial.binding()], &ReducePush { n: cur_n as u32 }, cur_n as u64)?;
        cur = partial.binding();
        cur_n = groups;
        rec.keep_alive(partial);
    }
    rec.dispatch(&k, &[cur, out.binding()], &ReducePush { n: cur_n as u32 }, cur_n as u64)
}

/// Element counts of the temporary partial-sum buffers [`reduce_sum`] allocates for `n` inputs (all alive until
/// the recorder's work completes); the VRAM planner counts them.
pub fn partial_lens(n: usize) -> Vec<usize> {
    let mut out = Vec::new();
    let mut cur = n;
    while cur > 0 && cur.div_ceil(BLOCK) > 1 {
        cur = cur.div_ceil(BLOCK);
        out.push(cur);
    }
    out
}

/// Convenience: the sum of `input[0..n]` on the host.
pub fn sum<V: ScanValue>(ctx: &Context, input: &GpuBuffer<V>, n: usize) -> GpuResult<V> {
    let out = GpuBuffer::<V>::new(ctx, &BufferDesc { name: "sum", len: 1, category: MemoryCategory::Other })?;
    let mut rec = ctx.recorder("sum")?;
    reduce_sum(&mut rec, input, n, &out)?;
    rec.submit_and_wait()?;
    Ok(ctx.download(&out)?[0])
}
