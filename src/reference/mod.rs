//! CPU twins of the GLSL kernels: the same arithmetic in plain Rust, used by the tests to check the kernels
//! (and usable as a slow fallback). One file per kernel family.

pub mod adam;
pub mod hashgrid;
pub mod mlp;
pub mod pipeline;
pub mod pose;
pub mod real;
pub mod render;
pub mod sh;
pub mod util;
