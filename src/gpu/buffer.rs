//! `GpuBuffer<T>`: a typed, named device-local storage buffer whose bytes are recorded in the memory ledger
//! under a category. Host access only through staging (`Context::upload` / `download`). `Binding` is a
//! (buffer, byte range) a kernel dispatch binds; one binding may not exceed `maxStorageBufferRange`.

use super::context::{lock, Context, DeviceShared};
use super::error::{GpuError, GpuResult, VkCheck};
use super::memory::MemoryCategory;
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::marker::PhantomData;
use std::sync::Arc;

/// Vulkan forbids empty buffers; an empty `GpuBuffer` still reserves this much.
pub const MIN_BUFFER_BYTES: u64 = 16;

#[derive(Clone, Debug)]
pub struct BufferDesc<'a> {
    pub name: &'a str,
    /// Number of elements of `T`.
    pub len: usize,
    pub category: MemoryCategory,
}

/// The bit pattern of [`super::ContextDesc::poison_buffers`]: a quiet NaN as f32.
pub const POISON: u32 = 0x7FC0_0000;

/// A raw allocation shared by typed buffers and staging buffers.
pub(crate) struct RawBuffer {
    pub raw: vk::Buffer,
    pub allocation: Option<Allocation>,
    pub bytes: u64,
    pub ledger_id: u64,
    pub name: Arc<str>,
}

impl RawBuffer {
    pub fn new(
        shared: &DeviceShared,
        ctx: Option<&Context>,
        name: &str,
        bytes: u64,
        category: MemoryCategory,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> GpuResult<Self> {
        let d = &shared.device;
        let info = vk::BufferCreateInfo::default()
            .size(bytes.max(MIN_BUFFER_BYTES))
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let raw = unsafe { d.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        let req = unsafe { d.get_buffer_memory_requirements(raw) };
        let alloc = lock(&shared.allocator).allocate(&AllocationCreateDesc {
            name,
            requirements: req,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match alloc {
            Ok(a) => a,
            Err(source) => {
                unsafe { d.destroy_buffer(raw, None) };
                return Err(GpuError::Alloc { name: name.to_owned(), bytes, source });
            }
        };
        if let Err(e) = unsafe { d.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) } {
            unsafe { d.destroy_buffer(raw, None) };
            let _ = lock(&shared.allocator).free(allocation);
            return Err(GpuError::Vulkan { op: "vkBindBufferMemory", res: e });
        }
        let ledger_id = lock(&shared.ledger).record_alloc(name, category, req.size);
        if let Some(ctx) = ctx {
            ctx.name_object(raw, name);
        }
        Ok(Self { raw, allocation: Some(allocation), bytes, ledger_id, name: Arc::from(name) })
    }

    /// Frees the buffer and its memory and removes it from the ledger.
    pub fn release(
        &mut self,
        shared_alloc: &mut gpu_allocator::vulkan::Allocator,
        ledger: &mut super::MemoryLedger,
        d: &ash::Device,
    ) {
        if let Some(a) = self.allocation.take() {
            unsafe { d.destroy_buffer(self.raw, None) };
            let _ = shared_alloc.free(a);
            ledger.record_free(self.ledger_id);
        }
    }
}

pub struct GpuBuffer<T: Pod> {
    pub(crate) shared: Arc<DeviceShared>,
    pub(crate) inner: RawBuffer,
    /// Texel buffer views of this buffer ([`GpuBuffer::texel_binding`]), destroyed before it.
    texels: super::texel::TexelViews,
    len: usize,
    category: MemoryCategory,
    _t: PhantomData<T>,
}

/// A byte range of a buffer as one descriptor binding.
#[derive(Clone, Debug)]
pub struct Binding {
    pub(crate) buffer: vk::Buffer,
    pub(crate) offset: u64,
    pub(crate) range: u64,
    pub(crate) name: Arc<str>,
    /// A uniform texel buffer view of the buffer ([`crate::gpu::LargeArray::texel_binding`]): bound to the
    /// kernel's texel slots (`TEXEL_BINDING_BASE` on), not to a storage-buffer binding.
    pub(crate) view: Option<vk::BufferView>,
}

impl<T: Pod> GpuBuffer<T> {
    pub fn new(ctx: &Context, desc: &BufferDesc) -> GpuResult<Self> {
        let bytes = (desc.len * std::mem::size_of::<T>()) as u64;
        let s = &ctx.shared;
        let inner =
            RawBuffer::new(s, Some(ctx), desc.name, bytes, desc.category, s.buffer_usage(), MemoryLocation::GpuOnly)?;
        if s.poison_buffers {
            let raw = inner.raw;
            ctx.one_shot(|d, cmd| unsafe {
                d.cmd_fill_buffer(cmd, raw, 0, vk::WHOLE_SIZE, POISON);
                let b = [vk::MemoryBarrier2::default()
                    .src_stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER)
                    .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                    .dst_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
                    .dst_access_mask(vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE)];
                d.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&b));
            })?;
        }
        Ok(Self {
            shared: s.clone(),
            inner,
            texels: Default::default(),
            len: desc.len,
            category: desc.category,
            _t: PhantomData,
        })
    }

    /// A new buffer holding `data` (uploaded through staging).
    pub fn from_slice(ctx: &Context, name: &str, category: MemoryCategory, data: &[T]) -> GpuResult<Self> {
        let b = Self::new(ctx, &BufferDesc { name, len: data.len(), category })?;
        ctx.upload(&b, 0, data)?;
        Ok(b)
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn size_bytes(&self) -> u64 {
        self.inner.bytes
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }

    pub fn category(&self) -> MemoryCategory {
        self.category
    }

    pub fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }

    /// The whole buffer as one binding.
    pub fn binding(&self) -> Binding {
        Binding {
            buffer: self.inner.raw,
            offset: 0,
            range: self.inner.bytes.max(MIN_BUFFER_BYTES),
            name: self.inner.name.clone(),
            view: None,
        }
    }

    /// The whole buffer as a uniform texel buffer of `format` (see [`super::texel`]), or `None` where the device
    /// cannot bind it so (too many texels, not a whole number of them, or an unsupported format).
    pub fn texel_binding(&self, format: vk::Format) -> GpuResult<Option<Binding>> {
        let max = self.shared.caps.max_texel_buffer_elements;
        self.texels.binding(&self.shared.device, max, self.binding(), self.inner.bytes, format)
    }

    /// Elements `[start, end)` as one binding (start must respect `minStorageBufferOffsetAlignment`).
    pub fn slice(&self, start: usize, end: usize) -> GpuResult<Binding> {
        let sz = std::mem::size_of::<T>() as u64;
        let align = self.shared.caps.min_storage_buffer_offset_alignment.max(1);
        let offset = start as u64 * sz;
        if start > end || end > self.len || offset % align != 0 || start == end {
            return Err(GpuError::Buffer {
                name: self.name().to_owned(),
                msg: format!("bad slice {start}..{end} of {} elements (offset alignment {align} bytes)", self.len),
            });
        }
        Ok(Binding {
            buffer: self.inner.raw,
            offset,
            range: (end - start) as u64 * sz,
            name: self.inner.name.clone(),
            view: None,
        })
    }

    /// The buffer's device address (for kernels that read it through `buffer_reference`).
    pub fn device_address(&self) -> GpuResult<u64> {
        if !self.shared.caps.buffer_device_address {
            return Err(GpuError::MissingCapability("bufferDeviceAddress"));
        }
        let info = vk::BufferDeviceAddressInfo::default().buffer(self.inner.raw);
        Ok(unsafe { self.shared.device.get_buffer_device_address(&info) })
    }
}

impl<T: Pod> Drop for GpuBuffer<T> {
    fn drop(&mut self) {
        let s = &self.shared;
        self.texels.destroy(&s.device);
        self.inner.release(&mut lock(&s.allocator), &mut lock(&s.ledger), &s.device);
    }
}
