//! Neural modules as Vulkan kernels, each with a CPU twin in `crate::reference`: the multiresolution hash grid
//! ([`hashgrid`]) and the fully fused MLP ([`mlp`]).

pub mod hashgrid;
