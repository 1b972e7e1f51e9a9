//! Uniform texel buffer views of [`GpuBuffer`](super::GpuBuffer)s, made on first use and destroyed with their
//! buffer. On lavapipe a kernel's `texelFetch` from a texel buffer compiles to a branch-free gather (an AVX2 gather
//! for 32-bit texels), where a read from a storage buffer or through a device address at a per-lane index is a loop
//! over the SIMD lanes with a branch each: the hash grid reads its tables this way on CPU devices
//! (docs/benchmarks.md). A view is bound to a kernel's texel slots (`TEXEL_BINDING_BASE` on) through a [`Binding`]
//! that carries it.

use super::buffer::Binding;
use super::error::{GpuError, GpuResult};
use ash::vk;
use std::sync::Mutex;

/// Bytes per texel of the formats the kernels read: R32, R32G32 and R32G32B32A32 SFLOAT, the three whose uniform
/// texel buffer support Vulkan makes mandatory.
pub fn texel_bytes(format: vk::Format) -> Option<u64> {
    match format {
        vk::Format::R32_SFLOAT => Some(4),
        vk::Format::R32G32_SFLOAT => Some(8),
        vk::Format::R32G32B32A32_SFLOAT => Some(16),
        _ => None,
    }
}

struct TexelView {
    view: vk::BufferView,
    format: vk::Format,
}

/// The views of one buffer, one per format.
#[derive(Default)]
pub(crate) struct TexelViews {
    views: Mutex<Vec<TexelView>>,
}

impl TexelViews {
    /// A binding of the whole buffer (`bytes` long, bound as `whole`) as texels of `format`, or `None` when the
    /// buffer holds more texels than `max_texels` (the device's `maxTexelBufferElements`), is not a whole number of
    /// texels, or the format is not one of [`texel_bytes`]'s.
    pub fn binding(
        &self,
        device: &ash::Device,
        max_texels: u32,
        whole: Binding,
        bytes: u64,
        format: vk::Format,
    ) -> GpuResult<Option<Binding>> {
        let Some(tb) = texel_bytes(format) else { return Ok(None) };
        if bytes == 0 || bytes % tb != 0 || bytes / tb > max_texels as u64 {
            return Ok(None);
        }
        let mut views = super::context::lock(&self.views);
        if let Some(v) = views.iter().find(|v| v.format == format) {
            return Ok(Some(Binding { view: Some(v.view), ..whole }));
        }
        let info = vk::BufferViewCreateInfo::default().buffer(whole.buffer).format(format).offset(0).range(bytes);
        let view = unsafe { device.create_buffer_view(&info, None) }
            .map_err(|res| GpuError::Vulkan { op: "vkCreateBufferView", res })?;
        views.push(TexelView { view, format });
        Ok(Some(Binding { view: Some(view), ..whole }))
    }

    /// Destroys every view (the owner calls this before destroying the buffer).
    pub fn destroy(&self, device: &ash::Device) {
        for v in super::context::lock(&self.views).drain(..) {
            unsafe { device.destroy_buffer_view(v.view, None) };
        }
    }
}
