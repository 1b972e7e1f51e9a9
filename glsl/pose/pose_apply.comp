// pose_apply: applies each training camera's SO3xR3 correction to its freshly generated rays (spec/nerfacto.md
// §2.4): origin += t, direction = R(w) direction, keeping the uncorrected direction for the backward pass.
// Runs only when the model's camera optimiser is on. Twin: src/reference/pose.rs `apply`.
// Bindings: 0 camera index per ray (uint[R]), 1 origins (float[3R], read-modify-written), 2 directions (float[3R],
//           read-modify-written), 3 uncorrected directions (float[3R], written).
// Push:     params (chunk-table address), shift, pose_offset (first float of the pose slot: 6 per camera), n_rays.
// Threads:  one invocation per ray, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "pose/pose_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer CamIdx { uint cam_idx[]; };
layout(std430, binding = 1) buffer Origins { float origins[]; };
layout(std430, binding = 2) buffer Dirs { float dirs[]; };
layout(std430, binding = 3) writeonly buffer RawDirs { float raw_dirs[]; };
layout(push_constant) uniform Push { uint64_t params; uint shift; uint pose_offset; uint n_rays; } pc;

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    uint base = pc.pose_offset + 6u * cam_idx[r];
    float p[6];
    for (uint k = 0u; k < 6u; ++k) p[k] = large_load_f32(pc.params, pc.shift, base + k);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    vec3 dc = so3_rotate(vec3(p[3], p[4], p[5]), d);
    for (uint k = 0u; k < 3u; ++k) {
        raw_dirs[3u * r + k] = d[k];
        origins[3u * r + k] += p[k];
        dirs[3u * r + k] = dc[k];
    }
}
