//! msnerf: multispectral neural radiance fields (nerfacto for B spectral bands) on Vulkan compute.
//!
//! Layers, one folder each: [`gpu`] (the Vulkan runtime), [`ops`] (generic compute operations), [`nn`] (encodings,
//! optimiser, parameter store), [`reference`] (CPU twins of every kernel), [`cli`] (the `msnerf` subcommands).

pub mod cli;
pub mod gpu;
pub mod nn;
pub mod ops;
pub mod reference;
pub mod shaders;
