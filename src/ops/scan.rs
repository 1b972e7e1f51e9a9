//! Exclusive prefix scans: whole-array (block scan, recursive scan of block sums, add-back) and segmented per
//! ray (one invocation per segment, serial inside it).

use super::{ScanValue, BLOCK};
use crate::gpu::{Binding, BufferDesc, GpuBuffer, GpuError, GpuResult, Kernel, MemoryCategory, Recorder};

crate::push_constants! {
    struct ScanPush {
        n: u32,
    }

    struct SegmentedScanPush {
        n_segments: u32,
    }
}

/// Records `output[i] = sum(input[0..i])` for i < n. `output` may be `input` (in place).
pub fn exclusive_scan<V: ScanValue>(
    rec: &mut Recorder,
    input: &GpuBuffer<V>,
    output: &GpuBuffer<V>,
    n: usize,
) -> GpuResult<()> {
    if n > input.len() || n > output.len() {
        return Err(GpuError::Buffer {
            name: output.name().into(),
            msg: format!("scan of {n} elements overruns the buffers"),
        });
    }
    if n == 0 {
        return Ok(());
    }
    scan_level::<V>(rec, input.binding(), output.binding(), n)
}

fn scan_level<V: ScanValue>(rec: &mut Recorder, input: Binding, output: Binding, n: usize) -> GpuResult<()> {
    let ctx = rec.context();
    let blocks = n.div_ceil(BLOCK);
    let sums = GpuBuffer::<V>::new(
        ctx,
        &BufferDesc { name: "scan block sums", len: blocks, category: MemoryCategory::Other },
    )?;
    let k_block = Kernel::<ScanPush>::new(ctx, V::SCAN_BLOCK)?;
    let push = ScanPush { n: n as u32 };
    rec.dispatch(&k_block, &[input, output.clone(), sums.binding()], &push, n as u64)?;
    if blocks > 1 {
        scan_level::<V>(rec, sums.binding(), sums.binding(), blocks)?;
        let k_add = Kernel::<ScanPush>::new(ctx, V::SCAN_ADD)?;
        rec.dispatch(&k_add, &[output, sums.binding()], &push, n as u64)?;
    }
    rec.keep_alive(sums);
    Ok(())
}

/// Records, for each segment s = [starts[s], starts[s+1]): `output[j] = sum(values[starts[s]..j])` and
/// `totals[s]` = the segment's sum. `starts` has n_segments + 1 non-decreasing entries.
pub fn segmented_exclusive_scan<V: ScanValue>(
    rec: &mut Recorder,
    values: &GpuBuffer<V>,
    starts: &GpuBuffer<u32>,
    output: &GpuBuffer<V>,
    totals: &GpuBuffer<V>,
    n_segments: usize,
) -> GpuResult<()> {
    if starts.len() < n_segments + 1 || totals.len() < n_segments {
        return Err(GpuError::Buffer {
            name: starts.name().into(),
            msg: format!("{n_segments} segments need {} starts and totals", n_segments + 1),
        });
    }
    let k = Kernel::<SegmentedScanPush>::new(rec.context(), V::SCAN_SEGMENTED)?;
    let bindings = [values.binding(), starts.binding(), output.binding(), totals.binding()];
    rec.dispatch(&k, &bindings, &SegmentedScanPush { n_segments: n_segments as u32 }, n_segments as u64)
}
