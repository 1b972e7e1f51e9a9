//! `LargeArray<T>`: one logical array stored as chunks of 2^shift elements, each chunk its own buffer of at
//! most `maxStorageBufferRange` bytes (128 MiB on lavapipe). Kernels reach any element through the chunk
//! table's device address (`glsl/common/large_array.glsl`); element-wise kernels can instead be dispatched
//! once per chunk with ordinary bindings ([`LargeArray::chunks`]). Table 1's 256 MiB hash grid is the reason.

use super::buffer::{Binding, BufferDesc, GpuBuffer};
use super::context::Context;
use super::error::{GpuError, GpuResult};
use super::memory::MemoryCategory;
use ash::vk;
use bytemuck::Pod;

pub struct LargeArray<T: Pod> {
    name: String,
    len: usize,
    shift: u32,
    chunks: Vec<GpuBuffer<T>>,
    /// Device addresses of the chunks (empty without bufferDeviceAddress).
    table: Option<GpuBuffer<u64>>,
}

/// Element counts of the chunk buffers [`LargeArray::with_chunk_shift`] creates for `len` elements (at least one
/// chunk); with `bufferDeviceAddress` it adds a chunk table of one `u64` per chunk. The VRAM planner uses this.
pub fn chunk_lens(len: usize, shift: u32) -> Vec<usize> {
    let chunk = 1usize << shift;
    let n_chunks = len.div_ceil(chunk).max(1);
    (0..n_chunks).map(|c| chunk.min(len - (c * chunk).min(len))).collect()
}

impl<T: Pod> LargeArray<T> {
    /// Chunks as large as one binding allows (a power of two of elements).
    pub fn new(ctx: &Context, name: &str, len: usize, category: MemoryCategory) -> GpuResult<Self> {
        let caps = ctx.caps();
        let max_bytes = caps.max_storage_buffer_range.min(caps.max_memory_allocation_size);
        let max_elems = (max_bytes / std::mem::size_of::<T>() as u64).max(1);
        let shift = 63 - max_elems.leading_zeros();
        Self::with_chunk_shift(ctx, name, len, category, shift)
    }

    /// Chunks of exactly 2^shift elements (the last one shorter).
    pub fn with_chunk_shift(
        ctx: &Context,
        name: &str,
        len: usize,
        category: MemoryCategory,
        shift: u32,
    ) -> GpuResult<Self> {
        let chunk = 1usize << shift;
        if (chunk * std::mem::size_of::<T>()) as u64 > ctx.caps().max_storage_buffer_range {
            return Err(GpuError::Buffer {
                name: name.into(),
                msg: format!("chunks of 2^{shift} elements exceed one binding"),
            });
        }
        let lens = chunk_lens(len, shift);
        let mut chunks = Vec::with_capacity(lens.len());
        for (c, &clen) in lens.iter().enumerate() {
            chunks.push(GpuBuffer::new(ctx, &BufferDesc { name: &format!("{name}[chunk {c}]"), len: clen, category })?);
        }
        let table = if ctx.caps().buffer_device_address {
            let addrs = chunks.iter().map(|c| c.device_address()).collect::<GpuResult<Vec<u64>>>()?;
            Some(GpuBuffer::from_slice(ctx, &format!("{name}[chunk table]"), category, &addrs)?)
        } else {
            None
        };
        Ok(Self { name: name.to_owned(), len, shift, chunks, table })
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// log2 of the elements per chunk (the `shift` kernels take).
    pub fn chunk_shift(&self) -> u32 {
        self.shift
    }

    pub fn chunks(&self) -> &[GpuBuffer<T>] {
        &self.chunks
    }

    /// Device address of the chunk table, for kernels using `common/large_array.glsl`.
    pub fn table_address(&self) -> GpuResult<u64> {
        self.table.as_ref().ok_or(GpuError::MissingCapability("bufferDeviceAddress"))?.device_address()
    }

    /// Every buffer a kernel touches through the table (for the recorder's barrier tracking).
    pub fn deps(&self) -> Vec<vk::Buffer> {
        self.chunks.iter().map(|c| c.raw()).chain(self.table.iter().map(|t| t.raw())).collect()
    }

    /// Chunk `chunk` as a uniform texel buffer of `format` ([`GpuBuffer::texel_binding`]).
    pub fn texel_binding(&self, chunk: usize, format: vk::Format) -> GpuResult<Option<Binding>> {
        let c = self.chunks.get(chunk).ok_or_else(|| GpuError::Buffer {
            name: self.name.clone(),
            msg: format!("chunk {chunk} of {}", self.chunks.len()),
        })?;
        c.texel_binding(format)
    }

    /// Writes `data` at logical element `offset`, split across chunks.
    pub fn upload(&self, ctx: &Context, offset: usize, data: &[T]) -> GpuResult<()> {
        if offset + data.len() > self.len {
            return Err(GpuError::Buffer {
                name: self.name.clone(),
                msg: format!("upload past the end ({} + {} > {})", offset, data.len(), self.len),
            });
        }
        let chunk = 1usize << self.shift;
        let mut i = 0;
        while i < data.len() {
            let g = offset + i;
            let (c, o) = (g / chunk, g % chunk);
            let n = (chunk - o).min(data.len() - i);
            ctx.upload(&self.chunks[c], o, &data[i..i + n])?;
            i += n;
        }
        Ok(())
    }

    /// Reads the whole logical array back.
    pub fn download(&self, ctx: &Context) -> GpuResult<Vec<T>> {
        let mut out = Vec::with_capacity(self.len);
        for c in &self.chunks {
            out.extend(ctx.download(c)?);
        }
        Ok(out)
    }
}
