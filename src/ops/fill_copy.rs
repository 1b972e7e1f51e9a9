//! `fill` and `copy` for any 4-byte element type (kernels `fill_u32`, `copy_u32`).

use crate::gpu::{GpuBuffer, GpuError, GpuResult, Kernel, Recorder};
use crate::shaders;
use bytemuck::Pod;

crate::push_constants! {
    struct FillPush {
        n: u32,
        offset: u32,
        value: u32,
    }
}

crate::push_constants! {
    struct CopyPush {
        n: u32,
        src_offset: u32,
        dst_offset: u32,
    }
}

fn check_word<T>(name: &str) -> GpuResult<()> {
    if std::mem::size_of::<T>() != 4 {
        return Err(GpuError::Buffer { name: name.into(), msg: "fill/copy need a 4-byte element type".into() });
    }
    Ok(())
}

fn check_range(name: &str, start: usize, n: usize, len: usize) -> GpuResult<()> {
    if start.checked_add(n).is_none_or(|e| e > len) || len > u32::MAX as usize {
        return Err(GpuError::Buffer {
            name: name.into(),
            msg: format!("range {start}..{} outside 0..{len}", start.saturating_add(n)),
        });
    }
    Ok(())
}

/// Elements one `fill_u32` invocation writes over the 8-aligned body of a range (8 floats per store).
const FILL_VEC: usize = 8;

/// `buf[start .. start + n] = value`.
pub fn fill<T: Pod>(rec: &mut Recorder, buf: &GpuBuffer<T>, value: T, start: usize, n: usize) -> GpuResult<()> {
    check_word::<T>(buf.name())?;
    check_range(buf.name(), start, n, buf.len())?;
    let value: u32 = bytemuck::cast(value);
    for (range, per) in super::aligned_split(start, start + n, FILL_VEC).into_iter().zip([1, FILL_VEC, 1]) {
        if range.is_empty() {
            continue;
        }
        let k = Kernel::<FillPush>::with_spec(rec.context(), &shaders::FILL_U32, &[("VEC", per as u32)])?;
        let push = FillPush { n: range.len() as u32, offset: range.start as u32, value };
        rec.dispatch(&k, &[buf.binding()], &push, (range.len() / per) as u64)?;
    }
    Ok(())
}

/// `dst[dst_start .. dst_start + n] = src[src_start .. src_start + n]`.
pub fn copy<T: Pod>(
    rec: &mut Recorder,
    src: &GpuBuffer<T>,
    src_start: usize,
    dst: &GpuBuffer<T>,
    dst_start: usize,
    n: usize,
) -> GpuResult<()> {
    check_word::<T>(src.name())?;
    check_range(src.name(), src_start, n, src.len())?;
    check_range(dst.name(), dst_start, n, dst.len())?;
    let k = Kernel::<CopyPush>::new(rec.context(), &shaders::COPY_U32)?;
    let push = CopyPush { n: n as u32, src_offset: src_start as u32, dst_offset: dst_start as u32 };
    rec.dispatch(&k, &[src.binding(), dst.binding()], &push, n as u64)
}
