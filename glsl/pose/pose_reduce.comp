// pose_reduce: turns each ray's (g_o, g_d) into the gradient of its camera's correction p = [t, w] and adds it to
// the pose slot of the gradient array: dL/dt = g_o, dL/dw = so3_rotate_grad_w(w, uncorrected direction, g_d)
// (fp32 atomicAdd through the chunk table; the pose slot lies inside one chunk). Twin: src/reference/pose.rs
// `camera_grad`.
// Bindings: 0 per-ray gradient (float[6R]), 1 uncorrected directions (float[3R]), 2 camera index per ray (uint[R]).
// Push:     params, grads (chunk-table addresses), shift, pose_offset, n_rays.
// Threads:  one invocation per ray, 64 per group, folded into 2D past 65535 groups.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "pose/pose_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer RayGrad { float ray_grad[]; };
layout(std430, binding = 1) readonly buffer RawDirs { float raw_dirs[]; };
layout(std430, binding = 2) readonly buffer CamIdx { uint cam_idx[]; };
layout(push_constant) uniform Push { uint64_t params; uint64_t grads; uint shift; uint pose_offset; uint n_rays; } pc;

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    float g[6];
    bool any_nonzero = false;
    for (uint k = 0u; k < 6u; ++k) {
        g[k] = ray_grad[6u * r + k];
        any_nonzero = any_nonzero || g[k] != 0.0;
    }
    if (!any_nonzero) return; // masked-out rays cost no atomics
    uint base = pc.pose_offset + 6u * cam_idx[r];
    vec3 w = vec3(large_load_f32(pc.params, pc.shift, base + 3u), large_load_f32(pc.params, pc.shift, base + 4u),
                  large_load_f32(pc.params, pc.shift, base + 5u));
    vec3 d = vec3(raw_dirs[3u * r], raw_dirs[3u * r + 1u], raw_dirs[3u * r + 2u]);
    vec3 gw = so3_rotate_grad_w(w, d, vec3(g[3], g[4], g[5]));
    LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, base));
    uint o = large_offset(pc.shift, base);
    for (uint k = 0u; k < 3u; ++k) {
        atomicAdd(chunk.v[o + k], g[k]);
        atomicAdd(chunk.v[o + 3u + k], gw[k]);
    }
}
