//! Uploads and readbacks through growable host-visible staging buffers (one per direction), copied with
//! `vkCmdCopyBuffer` in a one-shot submission. This is the only host path to device memory: lavapipe lets you
//! map device-local memory, NVIDIA does not, and code here behaves the same on both. Staging bytes are in the
//! ledger under `staging`. gpu-allocator only hands out HOST_COHERENT memory for these locations, so no
//! flush or invalidate is needed.

use super::buffer::{GpuBuffer, RawBuffer};
use super::context::{lock, Context};
use super::error::{GpuError, GpuResult};
use super::memory::{MemoryCategory, MemoryLedger};
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::Allocator;
use gpu_allocator::MemoryLocation;

/// Largest staging buffer; bigger transfers go in pieces of this size.
pub const MAX_STAGING_BYTES: u64 = 64 << 20;
/// Smallest staging buffer.
pub const MIN_STAGING_BYTES: u64 = 1 << 20;

/// Size of the staging buffer a transfer of `bytes` needs (a power of two in [1 MiB, 64 MiB]); each direction's
/// buffer only grows, so its final size is this of the largest transfer (the VRAM planner uses it).
pub fn staging_bytes(bytes: u64) -> u64 {
    bytes.next_power_of_two().clamp(MIN_STAGING_BYTES, MAX_STAGING_BYTES)
}

#[derive(Default)]
pub(crate) struct StagingBuffers {
    upload: Option<RawBuffer>,
    readback: Option<RawBuffer>,
}

impl StagingBuffers {
    pub fn release(&mut self, alloc: &mut Allocator, ledger: &mut MemoryLedger, d: &ash::Device) {
        for b in [self.upload.as_mut(), self.readback.as_mut()].into_iter().flatten() {
            b.release(alloc, ledger, d);
        }
        self.upload = None;
        self.readback = None;
    }
}

impl Context {
    /// Returns a staging buffer of at least `bytes` for the given direction, growing it when needed.
    fn staging<'a>(&self, slot: &'a mut Option<RawBuffer>, bytes: u64, upload: bool) -> GpuResult<&'a mut RawBuffer> {
        let s = &self.shared;
        if slot.as_ref().is_some_and(|b| b.bytes < bytes) {
            if let Some(mut old) = slot.take() {
                old.release(&mut lock(&s.allocator), &mut lock(&s.ledger), &s.device);
            }
        }
        if slot.is_none() {
            let size = staging_bytes(bytes);
            let (name, usage, loc) = if upload {
                ("staging upload", vk::BufferUsageFlags::TRANSFER_SRC, MemoryLocation::CpuToGpu)
            } else {
                ("staging readback", vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu)
            };
            *slot = Some(RawBuffer::new(s, Some(self), name, size, MemoryCategory::Staging, usage, loc)?);
        }
        Ok(slot.as_mut().expect("set above"))
    }

    /// Writes `data` into `dst` starting at element `offset`.
    pub fn upload<T: Pod>(&self, dst: &GpuBuffer<T>, offset: usize, data: &[T]) -> GpuResult<()> {
        if offset + data.len() > dst.len() {
            return Err(GpuError::Buffer {
                name: dst.name().to_owned(),
                msg: format!("upload of {} elements at {offset} overruns its {} elements", data.len(), dst.len()),
            });
        }
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let base = (offset * std::mem::size_of::<T>()) as u64;
        let mut guard = lock(&self.shared.staging);
        let mut done = 0u64;
        while done < bytes.len() as u64 {
            let n = (bytes.len() as u64 - done).min(MAX_STAGING_BYTES);
            let stage = self.staging(&mut guard.upload, n, true)?;
            let slice = stage
                .allocation
                .as_mut()
                .and_then(|a| a.mapped_slice_mut())
                .ok_or(GpuError::MissingCapability("host-mappable staging memory"))?;
            slice[..n as usize].copy_from_slice(&bytes[done as usize..(done + n) as usize]);
            let (src, dst_raw) = (stage.raw, dst.raw());
            self.one_shot(|d, cmd| unsafe {
                host_to_transfer_barrier(d, cmd);
                let region = vk::BufferCopy { src_offset: 0, dst_offset: base + done, size: n };
                d.cmd_copy_buffer(cmd, src, dst_raw, &[region]);
            })?;
            done += n;
        }
        Ok(())
    }

    /// Reads the whole buffer back.
    pub fn download<T: Pod>(&self, src: &GpuBuffer<T>) -> GpuResult<Vec<T>> {
        self.download_range(src, 0, src.len())
    }

    /// Reads elements `[start, end)` back.
    pub fn download_range<T: Pod>(&self, src: &GpuBuffer<T>, start: usize, end: usize) -> GpuResult<Vec<T>> {
        if start > end || end > src.len() {
            return Err(GpuError::Buffer {
                name: src.name().to_owned(),
                msg: format!("bad readback range {start}..{end} of {}", src.len()),
            });
        }
        let sz = std::mem::size_of::<T>();
        let mut out: Vec<T> = vec![T::zeroed(); end - start];
        let out_bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
        let base = (start * sz) as u64;
        let mut guard = lock(&self.shared.staging);
        let mut done = 0u64;
        while done < out_bytes.len() as u64 {
            let n = (out_bytes.len() as u64 - done).min(MAX_STAGING_BYTES);
            let stage = self.staging(&mut guard.readback, n, false)?;
            let (src_raw, dst) = (src.raw(), stage.raw);
            self.one_shot(|d, cmd| unsafe {
                let before = [vk::MemoryBarrier2::default()
                    .src_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
                    .src_access_mask(vk::AccessFlags2::MEMORY_WRITE)
                    .dst_stage_mask(vk::PipelineStageFlags2::COPY)
                    .dst_access_mask(vk::AccessFlags2::TRANSFER_READ)];
                d.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&before));
                let region = vk::BufferCopy { src_offset: base + done, dst_offset: 0, size: n };
                d.cmd_copy_buffer(cmd, src_raw, dst, &[region]);
                let after = [vk::MemoryBarrier2::default()
                    .src_stage_mask(vk::PipelineStageFlags2::COPY)
                    .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                    .dst_stage_mask(vk::PipelineStageFlags2::HOST)
                    .dst_access_mask(vk::AccessFlags2::HOST_READ)];
                d.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&after));
            })?;
            let slice = stage
                .allocation
                .as_ref()
                .and_then(|a| a.mapped_slice())
                .ok_or(GpuError::MissingCapability("host-mappable staging memory"))?;
            out_bytes[done as usize..(done + n) as usize].copy_from_slice(&slice[..n as usize]);
            done += n;
        }
        Ok(out)
    }
}

/// Makes earlier device work and host writes visible to a following transfer.
pub(crate) unsafe fn host_to_transfer_barrier(d: &ash::Device, cmd: vk::CommandBuffer) {
    let b = [vk::MemoryBarrier2::default()
        .src_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST)
        .src_access_mask(vk::AccessFlags2::MEMORY_WRITE | vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::HOST_WRITE)
        .dst_stage_mask(vk::PipelineStageFlags2::COPY)
        .dst_access_mask(vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE)];
    unsafe { d.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&b)) };
}
