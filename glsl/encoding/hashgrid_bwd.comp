// hashgrid_bwd: gradient of the hash encoding with respect to its parameters. For every (point, level, corner,
// feature): grad[entry, f] += weight * dL/dy[n, col + l*F + f], accumulated in fp32 with atomicAdd
// (VK_EXT_shader_atomic_float). The gradient array has the same chunking as the parameters.
// Bindings: 0 positions (float[3N]), 1 levels (HashLevel[L]), 2 dL/dy (float rows of dy_stride).
// Push:     grads (chunk-table address), shift, param_offset, n, dy_stride, dy_col.
// Spec:     0 F.
// Threads:  one invocation per (point, level) as in hashgrid_fwd; 128 per group.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 128
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
layout(std430, binding = 1) readonly buffer Levels { HashLevel levels[]; };
layout(std430, binding = 2) readonly buffer DLdy { float dy[]; };
layout(push_constant) uniform Push {
    uint64_t grads; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; uint pad;
} pc;

void main() {
    uint i = global_index();
    uint l = gl_WorkGroupID.z;
    if (i >= pc.n) return;
    HashLevel lv = levels[l];
    float g[F];
    bool any_nonzero = false;
    for (uint f = 0u; f < F; ++f) {
        g[f] = dy[i * pc.dy_stride + pc.dy_col + l * F + f];
        any_nonzero = any_nonzero || g[f] != 0.0;
    }
    if (!any_nonzero) return; // masked-out samples cost no atomics
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    for (uint c = 0u; c < 8u; ++c) {
        float w = corner_weight(c, frac);
        uint e = pc.param_offset + (lv.offset + hash_index(lv, corner_vertex(c, cell))) * F;
        LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, e));
        uint o = large_offset(pc.shift, e);
        for (uint f = 0u; f < F; ++f) atomicAdd(chunk.v[o + f], w * g[f]);
    }
}
