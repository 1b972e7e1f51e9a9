//! `HostBuffer`: a persistent, host-visible buffer that a command buffer copies from (inputs written by the host
//! before submission) or into (outputs read by the host after the submission has signalled). A training step keeps
//! one of each per step in flight, so it needs no one-shot staging submission of its own ([`super::staging`] is the
//! path for occasional transfers). gpu-allocator hands out HOST_COHERENT memory for these locations: no flush or
//! invalidate is needed. Bytes are in the ledger under `staging`.

use super::buffer::RawBuffer;
use super::context::{lock, Context, DeviceShared};
use super::error::{GpuError, GpuResult};
use super::memory::MemoryCategory;
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// Which way a [`HostBuffer`]'s bytes travel.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum HostDirection {
    /// Host writes, the device copies out of it.
    ToDevice,
    /// The device copies into it, the host reads.
    ToHost,
}

pub struct HostBuffer {
    shared: Arc<DeviceShared>,
    pub(crate) inner: RawBuffer,
}

impl HostBuffer {
    pub fn new(ctx: &Context, name: &str, bytes: u64, direction: HostDirection) -> GpuResult<Self> {
        let (usage, loc) = match direction {
            HostDirection::ToDevice => (vk::BufferUsageFlags::TRANSFER_SRC, MemoryLocation::CpuToGpu),
            HostDirection::ToHost => (vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu),
        };
        let inner = RawBuffer::new(&ctx.shared, Some(ctx), name, bytes, MemoryCategory::Staging, usage, loc)?;
        if inner.allocation.as_ref().and_then(|a| a.mapped_ptr()).is_none() {
            return Err(GpuError::MissingCapability("host-mappable staging memory"));
        }
        Ok(Self { shared: ctx.shared.clone(), inner })
    }

    pub fn bytes(&self) -> u64 {
        self.inner.bytes
    }

    pub(crate) fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }

    fn range_check(&self, at: u64, bytes: u64) -> GpuResult<()> {
        if at.checked_add(bytes).is_none_or(|e| e > self.inner.bytes) {
            return Err(GpuError::Buffer {
                name: self.inner.name.to_string(),
                msg: format!("{bytes} bytes at {at} overrun its {} bytes", self.inner.bytes),
            });
        }
        Ok(())
    }

    /// Writes `data` at byte offset `at`. Only while no submission that reads this buffer is in flight.
    pub fn write<T: Pod>(&mut self, at: u64, data: &[T]) -> GpuResult<()> {
        let src: &[u8] = bytemuck::cast_slice(data);
        self.range_check(at, src.len() as u64)?;
        let slice = super::staging::mapped_mut(&mut self.inner)?;
        slice[at as usize..at as usize + src.len()].copy_from_slice(src);
        Ok(())
    }

    /// Reads `n` elements from byte offset `at`. Only after the submission that wrote them has signalled.
    pub fn read<T: Pod>(&self, at: u64, n: usize) -> GpuResult<Vec<T>> {
        let bytes = (n * std::mem::size_of::<T>()) as u64;
        self.range_check(at, bytes)?;
        let slice = super::staging::mapped(&self.inner)?;
        Ok(bytemuck::pod_collect_to_vec(&slice[at as usize..(at + bytes) as usize]))
    }
}

impl Drop for HostBuffer {
    fn drop(&mut self) {
        let s = &self.shared;
        self.inner.release(&mut lock(&s.allocator), &mut lock(&s.ledger), &s.device);
    }
}
