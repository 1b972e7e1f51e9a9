// hashgrid_bwd_input: one level's share of the hash encoding's gradient with respect to its input positions (pose
// refinement needs it): dL/dp_d += dL/dy[l,f] * scale_l * sum_c (d weight_c / d frac_d) * theta_c[f].
// One dispatch per level (as hashgrid_fwd: the level's parameters in push constants, its table the only one the
// dispatch reads); the first level writes dL/dp, the others add to it, each invocation owning its point (the
// dispatches are ordered by barriers, so no atomics). Points whose output gradient is zero at the level skip the
// table reads.
// Bindings: 0 positions (float[3N]), 1 dL/dy (rows of dy_stride), 2 dL/dp (float[3N], written or added to); the
//           `_texel` variant (HASH_TEXEL) also texel 12, the level's chunk (hashgrid_entry.glsl).
// Push:     params (the level's chunk address, or the chunk table's address when HASH_CHUNKED), shift, param_offset
//           (first float of the level, in the chunk or in the array), n, dy_stride, dy_col (the level's first
//           column), scale, res, entries, weight (the level's coarse-to-fine weight, as in the forward: dL/dy is
//           multiplied by it).
// Spec:     0 F, 1 HASHED, 2 HASH_CHUNKED, 3 VEC_DY (read width of dL/dy, floats), 4 FIRST (1: write, 0: add).
// Threads:  one invocation per point, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "network/row_io.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(constant_id = 1) const uint HASHED = 1;
#ifndef HASH_TEXEL // the texel variants read the level's bound chunk: no chunk lookup, no HASH_CHUNKED
layout(constant_id = 2) const uint HASH_CHUNKED = 0;
#endif
layout(constant_id = 3) const uint VEC_DY = 1;
layout(constant_id = 4) const uint FIRST = 1;
#include "encoding/hashgrid_entry.glsl"
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
ROWS_DECLARE(1, dy, readonly)
layout(std430, binding = 2) buffer DLdp { float dp[]; };
layout(push_constant) uniform Push {
    uint64_t table; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; // table: the parameters
    float scale; uint res; uint entries; float weight;
} pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    float g[F];
    ROWS_LOAD(dy, VEC_DY, i * pc.dy_stride + pc.dy_col, g, 0u, F)
    [[unroll]] for (uint f = 0u; f < F; ++f) g[f] *= pc.weight;
    bool any_nonzero = false;
    [[unroll]] for (uint f = 0u; f < F; ++f) any_nonzero = any_nonzero || g[f] != 0.0;
    vec3 grad = vec3(0.0);
    if (any_nonzero) {
        HashLevel lv = HashLevel(pc.scale, pc.res, pc.entries, 0u, HASHED, 0u, 0u, 0u);
        vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
        uvec3 cell;
        vec3 frac;
        hash_cell(lv, p, cell, frac);
        [[unroll]] for (uint c = 0u; c < 8u; ++c) {
            uint e = pc.param_offset + hash_index_known(lv, corner_vertex(c, cell), HASHED != 0u) * F;
            float theta[F];
            [[unroll]] for (uint f = 0u; f < F; ++f) theta[f] = 0.0;
            HASH_ACCUMULATE_ENTRY(pc.table, pc.shift, e, 1.0, theta)
            float gtheta = 0.0; // sum_f dL/dy[l,f] * theta_c[f]
            [[unroll]] for (uint f = 0u; f < F; ++f) gtheta += g[f] * theta[f];
            [[unroll]] for (uint d = 0u; d < 3u; ++d) {
                float w = ((c >> d) & 1u) != 0u ? 1.0 : -1.0;
                [[unroll]] for (uint e2 = 0u; e2 < 3u; ++e2) {
                    if (e2 != d) w *= ((c >> e2) & 1u) != 0u ? frac[e2] : 1.0 - frac[e2];
                }
                grad[d] += w * gtheta;
            }
        }
        grad *= pc.scale;
    }
    if (FIRST == 0u) grad += vec3(dp[3u * i], dp[3u * i + 1u], dp[3u * i + 2u]);
    dp[3u * i] = grad.x;
    dp[3u * i + 1u] = grad.y;
    dp[3u * i + 2u] = grad.z;
}
