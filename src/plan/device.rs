//! What the planner needs to know about the device: how many bytes it reserves for a buffer of a given size
//! (its allocation rule) and the limits that shape the parameter store (binding size, allocation size, chunk
//! tables). With a device present the bytes come from the device itself (`Context::buffer_footprint`, the same
//! `vkGetDeviceBufferMemoryRequirements` number the ledger records); for another card they follow a documented
//! rule: round up to the profile's alignment (256 B), at least `min_buffer_bytes` (16 B).

use super::hardware::GpuProfile;
use crate::gpu::Context;
use serde::Serialize;

/// Where buffer byte counts come from.
#[derive(Clone)]
pub enum Footprint {
    /// Asked from this device.
    Device(Context),
    /// Rounded up to `align` bytes, at least `min` bytes.
    Rule { align: u64, min: u64 },
}

/// The device facts a plan depends on.
#[derive(Clone)]
pub struct DeviceRule {
    pub footprint: Footprint,
    pub max_storage_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    pub buffer_device_address: bool,
    /// One line for reports: which device or which rule.
    pub source: String,
}

/// The serialisable part of a [`DeviceRule`].
#[derive(Clone, Debug, Serialize)]
pub struct DeviceRuleInfo {
    pub source: String,
    pub max_storage_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    pub buffer_device_address: bool,
    pub param_chunk_shift: u32,
}

impl DeviceRule {
    /// Footprints and limits from a live device.
    pub fn from_context(ctx: &Context) -> Self {
        let c = ctx.caps();
        Self {
            footprint: Footprint::Device(ctx.clone()),
            max_storage_buffer_range: c.max_storage_buffer_range,
            max_memory_allocation_size: c.max_memory_allocation_size,
            buffer_device_address: c.buffer_device_address,
            source: format!("device {} ({}; vkGetDeviceBufferMemoryRequirements)", c.name, c.driver_name),
        }
    }

    /// Footprints by the profile's rule and its limits (no device needed).
    pub fn from_profile(g: &GpuProfile) -> Self {
        Self {
            footprint: Footprint::Rule { align: g.alignment, min: g.min_buffer_bytes },
            max_storage_buffer_range: g.max_storage_buffer_range,
            max_memory_allocation_size: g.max_memory_allocation_size,
            buffer_device_address: g.buffer_device_address,
            source: format!(
                "rule: sizes rounded up to {} B, at least {} B (no device)",
                g.alignment, g.min_buffer_bytes
            ),
        }
    }

    /// Bytes the device reserves for a buffer of `size` bytes.
    pub fn bytes(&self, size: u64) -> u64 {
        match &self.footprint {
            Footprint::Device(ctx) => ctx.buffer_footprint(size),
            Footprint::Rule { align, min } => size.max(*min).next_multiple_of(*align),
        }
    }

    /// The chunk shift of the parameter store's arrays on this device.
    pub fn param_chunk_shift(&self) -> u32 {
        crate::nn::params::chunk_shift_for(self.max_storage_buffer_range, self.max_memory_allocation_size)
    }

    pub fn info(&self) -> DeviceRuleInfo {
        DeviceRuleInfo {
            source: self.source.clone(),
            max_storage_buffer_range: self.max_storage_buffer_range,
            max_memory_allocation_size: self.max_memory_allocation_size,
            buffer_device_address: self.buffer_device_address,
            param_chunk_shift: self.param_chunk_shift(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rule_rounds_up_with_a_minimum() {
        let r = DeviceRule {
            footprint: Footprint::Rule { align: 256, min: 16 },
            max_storage_buffer_range: 1 << 27,
            max_memory_allocation_size: 1 << 31,
            buffer_device_address: true,
            source: String::new(),
        };
        assert_eq!(r.bytes(0), 256);
        assert_eq!(r.bytes(4), 256);
        assert_eq!(r.bytes(256), 256);
        assert_eq!(r.bytes(257), 512);
        assert_eq!(r.param_chunk_shift(), 25);
    }
}
