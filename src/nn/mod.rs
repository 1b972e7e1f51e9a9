//! Neural modules as Vulkan kernels, each with a CPU twin in `crate::reference`: the multiresolution hash grid
//! ([`hashgrid`]), the MLP (tiny-cuda-nn semantics, run as per-layer register tiles: [`mlp`]), the
//! spherical-harmonics direction encoding ([`sh`]), Adam ([`adam`]) and the one parameter store per model
//! ([`params`]).

pub mod adam;
pub mod hashgrid;
pub mod mlp;
pub mod params;
pub mod setting_error;
pub mod sh;

pub use setting_error::SettingError;

use crate::gpu::{GpuBuffer, LargeArray};

/// A module's parameters (or gradients): `array[offset ..]`.
#[derive(Copy, Clone)]
pub struct ParamSlice<'a> {
    pub array: &'a LargeArray<f32>,
    pub offset: usize,
}

/// Widest access (8, 4, 2 or 1 floats) that divides every given float offset or stride: the width kernels using
/// `glsl/network/row_io.glsl` read or write a run of a row with.
pub(crate) fn vec_width(offsets: &[usize]) -> u32 {
    [8usize, 4, 2].into_iter().find(|v| offsets.iter().all(|o| o % v == 0)).unwrap_or(1) as u32
}

/// A matrix stored as rows of a buffer: row i's columns start at `i * stride + col`.
#[derive(Copy, Clone)]
pub struct RowSlice<'a> {
    pub buf: &'a GpuBuffer<f32>,
    pub stride: usize,
    pub col: usize,
}
