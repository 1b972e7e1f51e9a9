//! Neural modules as Vulkan kernels, each with a CPU twin in `crate::reference`: the multiresolution hash grid
//! ([`hashgrid`]), the MLP (tiny-cuda-nn semantics, run as per-layer register tiles: [`mlp`]), the
//! spherical-harmonics direction encoding ([`sh`]), Adam ([`adam`]) and the one parameter store per model
//! ([`params`]).

pub mod adam;
pub mod hashgrid;
pub mod mlp;
pub mod params;
pub mod sh;

use crate::gpu::{GpuBuffer, LargeArray};

/// A module's parameters (or gradients): `array[offset ..]`.
#[derive(Copy, Clone)]
pub struct ParamSlice<'a> {
    pub array: &'a LargeArray<f32>,
    pub offset: usize,
}

/// A matrix stored as rows of a buffer: row i's columns start at `i * stride + col`.
#[derive(Copy, Clone)]
pub struct RowSlice<'a> {
    pub buf: &'a GpuBuffer<f32>,
    pub stride: usize,
    pub col: usize,
}
