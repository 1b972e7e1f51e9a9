// hashgrid_bwd_input: gradient of the hash encoding with respect to its input positions (pose refinement needs it):
// dL/dp_d = sum over levels l, features f of dL/dy[l,f] * scale_l * sum_c (d weight_c / d frac_d) * theta_c[f].
// Each invocation owns one point and loops over the levels, so no atomics are needed.
// Bindings: 0 positions (float[3N]), 1 levels (HashLevel[L]), 2 dL/dy (rows of dy_stride), 3 dL/dp (float[3N], written).
// Push:     params (chunk-table address), shift, param_offset, n, n_levels, dy_stride, dy_col.
// Spec:     0 F.
// Threads:  one invocation per point, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
layout(std430, binding = 1) readonly buffer Levels { HashLevel levels[]; };
layout(std430, binding = 2) readonly buffer DLdy { float dy[]; };
layout(std430, binding = 3) writeonly buffer DLdp { float dp[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint param_offset; uint n; uint n_levels; uint dy_stride; uint dy_col;
} pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    vec3 grad = vec3(0.0);
    for (uint l = 0u; l < pc.n_levels; ++l) {
        HashLevel lv = levels[l];
        uvec3 cell;
        vec3 frac;
        hash_cell(lv, p, cell, frac);
        vec3 dlev = vec3(0.0);
        for (uint c = 0u; c < 8u; ++c) {
            uint e = pc.param_offset + (lv.offset + hash_index(lv, corner_vertex(c, cell))) * F;
            LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.params, pc.shift, e));
            uint o = large_offset(pc.shift, e);
            float gtheta = 0.0; // sum_f dL/dy[l,f] * theta_c[f]
            for (uint f = 0u; f < F; ++f) gtheta += dy[i * pc.dy_stride + pc.dy_col + l * F + f] * chunk.v[o + f];
            for (uint d = 0u; d < 3u; ++d) {
                float w = ((c >> d) & 1u) != 0u ? 1.0 : -1.0;
                for (uint e2 = 0u; e2 < 3u; ++e2) {
                    if (e2 != d) w *= ((c >> e2) & 1u) != 0u ? frac[e2] : 1.0 - frac[e2];
                }
                dlev[d] += w * gtheta;
            }
        }
        grad += dlev * lv.scale;
    }
    dp[3u * i] = grad.x;
    dp[3u * i + 1u] = grad.y;
    dp[3u * i + 2u] = grad.z;
}
