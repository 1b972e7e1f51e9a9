//! Uploads and readbacks through growable host-visible staging buffers (one per direction), copied with
//! `vkCmdCopyBuffer` in a one-shot submission. This is the only host path to device memory: lavapipe lets you
//! map device-local memory, NVIDIA does not, and code here behaves the same on both. Staging bytes are in the
//! ledger under `staging`. gpu-allocator only hands out HOST_COHERENT memory for these locations, so no
//! flush or invalidate is needed.

use super::buffer::{GpuBuffer, RawBuffer};
use super::context::{lock, Context};
use super::error::{GpuError, GpuResult};
use super::host_clock::HostWork;
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
        let t = std::time::Instant::now();
        let r = self.upload_raw(&Part::upload(dst, offset, data)?);
        self.add_host_time(HostWork::Upload, t);
        r
    }

    /// Reads the whole buffer back.
    pub fn download<T: Pod>(&self, src: &GpuBuffer<T>) -> GpuResult<Vec<T>> {
        self.download_range(src, 0, src.len())
    }

    /// Reads elements `[start, end)` back.
    pub fn download_range<T: Pod>(&self, src: &GpuBuffer<T>, start: usize, end: usize) -> GpuResult<Vec<T>> {
        let t = std::time::Instant::now();
        let r = self.download_raw(&Part::download(src, start, end)?);
        self.add_host_time(HostWork::Readback, t);
        Ok(bytemuck::pod_collect_to_vec(&r?))
    }
}

/// One buffer range of a batched transfer ([`Context::upload_parts`], [`Context::download_parts`]): several
/// ranges go through one staging buffer and one submission, so a training step waits once for all its inputs and
/// once for all its outputs instead of once per buffer.
pub struct Part<'a> {
    raw: vk::Buffer,
    base: u64,
    bytes: u64,
    data: &'a [u8],
}

impl<'a> Part<'a> {
    /// `data` to be written into `dst` from element `offset`.
    pub fn upload<T: Pod>(dst: &'a GpuBuffer<T>, offset: usize, data: &'a [T]) -> GpuResult<Self> {
        if offset + data.len() > dst.len() {
            return Err(GpuError::Buffer {
                name: dst.name().to_owned(),
                msg: format!("upload of {} elements at {offset} overruns its {} elements", data.len(), dst.len()),
            });
        }
        let sz = std::mem::size_of::<T>() as u64;
        let data: &[u8] = bytemuck::cast_slice(data);
        Ok(Self { raw: dst.raw(), base: offset as u64 * sz, bytes: data.len() as u64, data })
    }

    /// Elements `[start, end)` of `src`, to be read back.
    pub fn download<T: Pod>(src: &'a GpuBuffer<T>, start: usize, end: usize) -> GpuResult<Self> {
        if start > end || end > src.len() {
            return Err(GpuError::Buffer {
                name: src.name().to_owned(),
                msg: format!("bad readback range {start}..{end} of {}", src.len()),
            });
        }
        let sz = std::mem::size_of::<T>() as u64;
        Ok(Self { raw: src.raw(), base: start as u64 * sz, bytes: (end - start) as u64 * sz, data: &[] })
    }
}

/// Where each part lies in a staging buffer (16-byte aligned), and the bytes they take together.
fn pack(parts: &[Part]) -> (Vec<u64>, u64) {
    let mut at = Vec::with_capacity(parts.len());
    let mut end = 0u64;
    for p in parts {
        at.push(end);
        end = (end + p.bytes).next_multiple_of(16);
    }
    (at, end)
}

impl Context {
    /// Every part's data written into its buffer, in one submission (larger batches than the biggest staging
    /// buffer go part by part).
    pub fn upload_parts(&self, parts: &[Part]) -> GpuResult<()> {
        let t = std::time::Instant::now();
        let r = self.upload_parts_inner(parts);
        self.add_host_time(HostWork::Upload, t);
        r
    }

    fn upload_parts_inner(&self, parts: &[Part]) -> GpuResult<()> {
        let (at, total) = pack(parts);
        if total > MAX_STAGING_BYTES {
            for p in parts {
                self.upload_raw(p)?;
            }
            return Ok(());
        }
        let mut guard = lock(&self.shared.staging);
        let stage = self.staging(&mut guard.upload, total.max(1), true)?;
        let slice = mapped_mut(stage)?;
        for (p, &o) in parts.iter().zip(&at) {
            slice[o as usize..(o + p.bytes) as usize].copy_from_slice(p.data);
        }
        let src = stage.raw;
        self.one_shot(|d, cmd| unsafe {
            host_to_transfer_barrier(d, cmd);
            for (p, &o) in parts.iter().zip(&at) {
                if p.bytes > 0 {
                    d.cmd_copy_buffer(
                        cmd,
                        src,
                        p.raw,
                        &[vk::BufferCopy { src_offset: o, dst_offset: p.base, size: p.bytes }],
                    );
                }
            }
        })
    }

    /// Every part's range read back, in one submission: one byte vector per part (`bytemuck::pod_collect_to_vec`
    /// turns it into elements).
    pub fn download_parts(&self, parts: &[Part]) -> GpuResult<Vec<Vec<u8>>> {
        let t = std::time::Instant::now();
        let r = self.download_parts_inner(parts);
        self.add_host_time(HostWork::Readback, t);
        r
    }

    fn download_parts_inner(&self, parts: &[Part]) -> GpuResult<Vec<Vec<u8>>> {
        let (at, total) = pack(parts);
        if total > MAX_STAGING_BYTES {
            return parts.iter().map(|p| self.download_raw(p)).collect();
        }
        let mut guard = lock(&self.shared.staging);
        let stage = self.staging(&mut guard.readback, total.max(1), false)?;
        let dst = stage.raw;
        self.one_shot(|d, cmd| unsafe {
            transfer_barriers(d, cmd, true);
            for (p, &o) in parts.iter().zip(&at) {
                if p.bytes > 0 {
                    d.cmd_copy_buffer(
                        cmd,
                        p.raw,
                        dst,
                        &[vk::BufferCopy { src_offset: p.base, dst_offset: o, size: p.bytes }],
                    );
                }
            }
            transfer_barriers(d, cmd, false);
        })?;
        let slice = mapped(stage)?;
        Ok(parts.iter().zip(&at).map(|(p, &o)| slice[o as usize..(o + p.bytes) as usize].to_vec()).collect())
    }

    fn upload_raw(&self, p: &Part) -> GpuResult<()> {
        let mut guard = lock(&self.shared.staging);
        let mut done = 0u64;
        while done < p.bytes {
            let n = (p.bytes - done).min(MAX_STAGING_BYTES);
            let stage = self.staging(&mut guard.upload, n, true)?;
            let slice = mapped_mut(stage)?;
            slice[..n as usize].copy_from_slice(&p.data[done as usize..(done + n) as usize]);
            let (src, dst) = (stage.raw, p.raw);
            self.one_shot(|d, cmd| unsafe {
                host_to_transfer_barrier(d, cmd);
                let region = vk::BufferCopy { src_offset: 0, dst_offset: p.base + done, size: n };
                d.cmd_copy_buffer(cmd, src, dst, &[region]);
            })?;
            done += n;
        }
        Ok(())
    }

    fn download_raw(&self, p: &Part) -> GpuResult<Vec<u8>> {
        let mut out = vec![0u8; p.bytes as usize];
        let mut guard = lock(&self.shared.staging);
        let mut done = 0u64;
        while done < p.bytes {
            let n = (p.bytes - done).min(MAX_STAGING_BYTES);
            let stage = self.staging(&mut guard.readback, n, false)?;
            let (src, dst) = (p.raw, stage.raw);
            self.one_shot(|d, cmd| unsafe {
                transfer_barriers(d, cmd, true);
                let region = vk::BufferCopy { src_offset: p.base + done, dst_offset: 0, size: n };
                d.cmd_copy_buffer(cmd, src, dst, &[region]);
                transfer_barriers(d, cmd, false);
            })?;
            let slice = mapped(stage)?;
            out[done as usize..(done + n) as usize].copy_from_slice(&slice[..n as usize]);
            done += n;
        }
        Ok(out)
    }
}

/// A host-visible buffer's bytes as the host sees them (staging and [`super::HostBuffer`]).
pub(crate) fn mapped(stage: &RawBuffer) -> GpuResult<&[u8]> {
    stage
        .allocation
        .as_ref()
        .and_then(|a| a.mapped_slice())
        .ok_or(GpuError::MissingCapability("host-mappable staging memory"))
}

pub(crate) fn mapped_mut(stage: &mut RawBuffer) -> GpuResult<&mut [u8]> {
    stage
        .allocation
        .as_mut()
        .and_then(|a| a.mapped_slice_mut())
        .ok_or(GpuError::MissingCapability("host-mappable staging memory"))
}

/// Readback barriers: before the copy (earlier device writes visible to it) or after it (its writes visible to
/// the host).
unsafe fn transfer_barriers(d: &ash::Device, cmd: vk::CommandBuffer, before: bool) {
    let b = if before {
        vk::MemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
            .src_access_mask(vk::AccessFlags2::MEMORY_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::COPY)
            .dst_access_mask(vk::AccessFlags2::TRANSFER_READ)
    } else {
        vk::MemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::COPY)
            .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::HOST)
            .dst_access_mask(vk::AccessFlags2::HOST_READ)
    };
    unsafe { d.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&[b])) };
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
