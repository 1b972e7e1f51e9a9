//! The kernels test binary: GPU kernels against their CPU twins, outside oracles and finite differences; the GPU runtime. One binary per layer, each former test file a module
//! (issue 24: five test binaries to link instead of one per file).

#[path = "../common/mod.rs"]
mod common;

mod gpu_runtime;
mod large_array;
mod nerf_normals;
mod nn_adam;
mod nn_hashgrid;
mod nn_mlp;
mod nn_params;
mod nn_sh;
mod ops_util;
mod oracle_nerfstudio;
mod pose_refinement;
mod render_kernels;
