//! Neural modules as Vulkan kernels, each with a CPU twin in `crate::reference`: the multiresolution hash grid
//! ([`hashgrid`]) and the fully fused MLP ([`mlp`]).

pub mod hashgrid;
pub mod mlp;

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
