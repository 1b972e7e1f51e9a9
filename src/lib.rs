//! msnerf: multispectral neural radiance fields (nerfacto for B spectral bands) on Vulkan compute.
//!
//! Layers, one folder each: [`gpu`] (the Vulkan runtime), [`ops`] (generic compute operations), [`nn`] (neural
//! modules: hash grid, MLP, SH, Adam, parameter store), [`data`] (datasets, image readers, poses, cameras, the host image cache),
//! [`reference`] (CPU twins of every kernel), [`output`] (metrics, rasters, previews, point clouds, cloud
//! comparison), [`products`] (what is made from a trained run), [`sweep`] (accuracy against training time), [`cli`]
//! (the `msnerf` subcommands).

pub mod bench;
pub mod cli;
pub mod data;
pub mod geo;
pub mod gpu;
pub mod maths;
pub mod nerf;
pub mod nn;
pub mod ops;
pub mod output;
pub mod plan;
pub mod poses;
pub mod process;
pub mod products;
pub mod reference;
pub mod rig;
pub mod scale;
pub mod sfm;
pub mod shaders;
pub mod sim;
pub mod sweep;
pub mod util;
