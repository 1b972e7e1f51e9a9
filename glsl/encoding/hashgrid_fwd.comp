// hashgrid_fwd: multiresolution hash encoding forward. out[n, col + l*F + f] = sum over the 8 corners of
// weight * theta[level l, corner entry, f]. The invocations of level 0 also write the padding columns
// [col + L*F, col + pad_to) with pad_value (zeros for the density MLP, ones for tcnn's bias quirk).
// Bindings: 0 positions (float[3N], in [0,1]^3), 1 levels (HashLevel[L]), 2 output (float rows of out_stride).
// Push:     params (chunk-table address), shift, param_offset (floats, first float of the grid), n, n_levels,
//           out_stride, out_col, pad_to, pad_value.
// Spec:     0 F (features per level).
// Threads:  one invocation per (point, level): points along x (folded into y past 65535 groups), level = z,
//           so one workgroup reads one level's table (tcnn's cache-friendly mapping). 128 per group.
#version 460
#define WG_SIZE 128
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
layout(std430, binding = 1) readonly buffer Levels { HashLevel levels[]; };
layout(std430, binding = 2) writeonly buffer Output { float outv[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint param_offset; uint n; uint n_levels;
    uint out_stride; uint out_col; uint pad_to; float pad_value;
} pc;

void main() {
    uint i = global_index();
    uint l = gl_WorkGroupID.z;
    if (i >= pc.n) return;
    HashLevel lv = levels[l];
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    float acc[F];
    for (uint f = 0u; f < F; ++f) acc[f] = 0.0;
    for (uint c = 0u; c < 8u; ++c) {
        float w = corner_weight(c, frac);
        uint g = pc.param_offset + (lv.offset + hash_index(lv, corner_vertex(c, cell))) * F;
        LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.params, pc.shift, g));
        uint o = large_offset(pc.shift, g);
        for (uint f = 0u; f < F; ++f) acc[f] += w * chunk.v[o + f];
    }
    uint row = i * pc.out_stride + pc.out_col;
    for (uint f = 0u; f < F; ++f) outv[row + l * F + f] = acc[f];
    if (l == 0u) {
        for (uint k = pc.n_levels * F; k < pc.pad_to; ++k) outv[row + k] = pc.pad_value;
    }
}
