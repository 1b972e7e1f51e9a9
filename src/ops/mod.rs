//! Generic compute operations built on the runtime: fill, copy, a NaN/Inf check, sum reduction and exclusive prefix scans
//! (whole-array and segmented per ray). Each records into a [`Recorder`](crate::gpu::Recorder) and has a CPU
//! twin in [`crate::reference::util`].

mod check;
mod fill_copy;
mod reduce;
mod scan;

pub use check::{record_check_finite, record_check_finite_slot};
pub use fill_copy::{copy, fill};
pub use reduce::{partial_lens, reduce_sum, sum};
pub use scan::{exclusive_scan, segmented_exclusive_scan};

use crate::gpu::ShaderBlob;
use crate::shaders;
use bytemuck::Pod;

/// Splits elements `[start, end)` for kernels that take `vec` consecutive elements per invocation where they can:
/// the unaligned head, the body of whole `vec`-aligned groups and the tail (each possibly empty).
pub fn aligned_split(start: usize, end: usize, vec: usize) -> [std::ops::Range<usize>; 3] {
    let head = start.next_multiple_of(vec).min(end);
    let body = head + (end - head) / vec * vec;
    [start..head, head..body, body..end]
}

/// Element types the generic reduce and scan kernels come in.
pub trait ScanValue: Pod + Default + std::fmt::Debug {
    const REDUCE: &'static ShaderBlob;
    const SCAN_BLOCK: &'static ShaderBlob;
    const SCAN_ADD: &'static ShaderBlob;
    const SCAN_SEGMENTED: &'static ShaderBlob;
}

impl ScanValue for f32 {
    const REDUCE: &'static ShaderBlob = &shaders::REDUCE_SUM_F32;
    const SCAN_BLOCK: &'static ShaderBlob = &shaders::SCAN_BLOCK_F32;
    const SCAN_ADD: &'static ShaderBlob = &shaders::SCAN_ADD_F32;
    const SCAN_SEGMENTED: &'static ShaderBlob = &shaders::SCAN_SEGMENTED_F32;
}

impl ScanValue for u32 {
    const REDUCE: &'static ShaderBlob = &shaders::REDUCE_SUM_U32;
    const SCAN_BLOCK: &'static ShaderBlob = &shaders::SCAN_BLOCK_U32;
    const SCAN_ADD: &'static ShaderBlob = &shaders::SCAN_ADD_U32;
    const SCAN_SEGMENTED: &'static ShaderBlob = &shaders::SCAN_SEGMENTED_U32;
}

/// Block width of the reduce and scan kernels (their `local_size_x`).
pub const BLOCK: usize = 256;

#[cfg(test)]
mod split_tests {
    use super::aligned_split;

    #[test]
    fn aligned_split_covers_the_range_with_an_aligned_body() {
        assert_eq!(aligned_split(3, 29, 8), [3..8, 8..24, 24..29]);
        assert_eq!(aligned_split(8, 16, 8), [8..8, 8..16, 16..16]);
        assert_eq!(aligned_split(5, 7, 8), [5..7, 7..7, 7..7]);
        assert_eq!(aligned_split(0, 0, 8), [0..0, 0..0, 0..0]);
    }
}
