// hashgrid_bwd_input: the hash encoding's gradient with respect to its input positions (pose refinement needs it):
// dL/dp_d = sum over levels l of dL/dy[l,f] * scale_l * sum_c (d weight_c / d frac_d) * theta_c[f].
// Two dispatch shapes (src/nn/hashgrid.rs):
// - per level (the default on CPU devices): one dispatch per level, as hashgrid_fwd (the level's parameters in push
//   constants, its table the only one the dispatch reads); the first level writes dL/dp, the others add to it, each
//   invocation owning its point (the dispatches are ordered by barriers, so no atomics);
// - `_levels` (build.rs defines HASH_LEVELS; the default on GPUs): one dispatch, each invocation walking the levels
//   in order (as tcnn's input gradient does), summing in registers and writing once: no barrier per level. The
//   sum's order is the per-level dispatches' order.
// Points whose output gradient is zero at a level skip that level's table reads.
// Bindings: 0 positions (float[3N]), 1 dL/dy (rows of dy_stride), 2 dL/dp (float[3N], written or added to); the
//           `_texel` variant (HASH_TEXEL) also texel 12, the level's chunk (hashgrid_entry.glsl); the `_levels`
//           variant also 3, the levels (HashLevel[L]).
// Push:     params (the chunk address, or the chunk table's address when HASH_CHUNKED), shift, param_offset (first
//           float of the level, or of the grid for `_levels`, in the chunk or in the array), n, dy_stride, dy_col
//           (the level's first column, or the grid's); per level: scale, res, entries, weight (the level's
//           coarse-to-fine weight, as in the forward: dL/dy is multiplied by it); `_levels`: active_levels (level
//           l's weight is clamp(active_levels - l, 0, 1)) and n_levels.
// Spec:     0 F, 1 HASHED (per level only), 2 HASH_CHUNKED, 3 VEC_DY (read width of dL/dy, floats), 4 FIRST (per
//           level only; 1: write, 0: add).
// Threads:  one invocation per point, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "network/row_io.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
#ifndef HASH_LEVELS
layout(constant_id = 1) const uint HASHED = 1;
#endif
#ifndef HASH_TEXEL // the texel variants read the level's bound chunk: no chunk lookup, no HASH_CHUNKED
layout(constant_id = 2) const uint HASH_CHUNKED = 0;
#endif
layout(constant_id = 3) const uint VEC_DY = 1;
#ifndef HASH_LEVELS
layout(constant_id = 4) const uint FIRST = 1;
#endif
#include "encoding/hashgrid_entry.glsl"
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
ROWS_DECLARE(1, dy, readonly)
layout(std430, binding = 2) buffer DLdp { float dp[]; };
#ifdef HASH_LEVELS
#ifdef HASH_TEXEL
#error "the all-levels variant reads through device addresses"
#endif
layout(std430, binding = 3) readonly buffer Levels { HashLevel levels[]; };
layout(push_constant) uniform Push {
    uint64_t table; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; // table: the parameters
    float active_levels; uint n_levels;
} pc;
#else
layout(push_constant) uniform Push {
    uint64_t table; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; // table: the parameters
    float scale; uint res; uint entries; float weight;
} pc;
#endif

// Level lv's term of dL/dp for point p, given its F output gradients g (already weighted) and its first float
// `first` in the parameters.
vec3 level_grad(HashLevel lv, bool hashed, uint first, vec3 p, float g[F]) {
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    vec3 grad = vec3(0.0);
    [[unroll]] for (uint c = 0u; c < 8u; ++c) {
        uint e = first + hash_index_known(lv, corner_vertex(c, cell), hashed) * F;
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
    return grad * lv.scale;
}

// dL/dy's F columns from `col`, times `weight`; whether any is non-zero.
bool load_dy(uint i, uint col, float weight, out float g[F]) {
    ROWS_LOAD(dy, VEC_DY, i * pc.dy_stride + col, g, 0u, F)
    bool any_nonzero = false;
    [[unroll]] for (uint f = 0u; f < F; ++f) {
        g[f] *= weight;
        any_nonzero = any_nonzero || g[f] != 0.0;
    }
    return any_nonzero;
}

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    float g[F];
#ifdef HASH_LEVELS
    vec3 grad = vec3(0.0);
    for (uint l = 0u; l < pc.n_levels; ++l) {
        float weight = clamp(pc.active_levels - float(l), 0.0, 1.0);
        if (weight == 0.0) break; // held-back levels: every finer one is held back too
        HashLevel lv = levels[l];
        if (load_dy(i, pc.dy_col + l * F, weight, g)) {
            grad = level_grad(lv, lv.hashed != 0u, pc.param_offset + lv.offset * F, p, g) + grad;
        }
    }
#else
    vec3 grad = vec3(0.0);
    if (load_dy(i, pc.dy_col, pc.weight, g)) {
        HashLevel lv = HashLevel(pc.scale, pc.res, pc.entries, 0u, HASHED, 0u, 0u, 0u);
        grad = level_grad(lv, HASHED != 0u, pc.param_offset, p, g);
    }
    if (FIRST == 0u) grad += vec3(dp[3u * i], dp[3u * i + 1u], dp[3u * i + 2u]);
#endif
    dp[3u * i] = grad.x;
    dp[3u * i + 1u] = grad.y;
    dp[3u * i + 2u] = grad.z;
}
