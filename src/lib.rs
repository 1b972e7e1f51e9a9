//! msnerf: multispectral neural radiance fields (nerfacto for B spectral bands) on Vulkan compute.
pub mod data;
