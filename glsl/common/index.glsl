// index.glsl: invocation indexing shared by all 1D kernels.
// The host folds a 1D dispatch of more than maxComputeWorkGroupCount[0] (65535) groups into a 2D grid
// (src/gpu/kernel.rs `fold_groups`), so kernels recover the linear index here and bound-check it.
//
// Kernels define WG_SIZE (their local_size_x) before including this file and never read gl_WorkGroupSize:
// Debian 12's glslang + SPIRV-Tools (2023.2) at -O fold `x * gl_WorkGroupSize.x` to `x`, silently. build.rs
// rejects any kernel that mentions gl_WorkGroupSize.
#ifndef WG_SIZE
#error "define WG_SIZE (the kernel's local_size_x) before including common/index.glsl"
#endif

// Linear index of this workgroup in a folded 1D dispatch.
uint group_index() {
    return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
}

// Linear index of this invocation in a folded 1D dispatch.
uint global_index() {
    return group_index() * WG_SIZE + gl_LocalInvocationID.x;
}
