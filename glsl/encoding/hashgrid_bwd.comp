// hashgrid_bwd: one level of the hash encoding's gradient with respect to its parameters. For every (point, corner,
// feature): grad[entry, f] += weight * dL/dy[n, col + f], accumulated in fp32 with atomicAdd
// (VK_EXT_shader_atomic_float). The gradient array has the same chunking as the parameters.
// One dispatch per level with the level's parameters in push constants (as hashgrid_fwd); a point's F output
// gradients are read in one access. Points whose output gradient is zero (masked-out samples) issue no atomics.
// The `_prefetch` variant (build.rs defines HASH_PREFETCH; CPU devices): before its atomics an invocation gathers
// the 8 corners' entries of the gradient table through a texel view, and ANDs their sum's bits with a zero push
// constant into the atomics' addresses. On lavapipe a texel fetch is a gather whose 8 lanes' cache misses overlap,
// while every locked add waits for its own (x86 locked instructions are full fences); with the lines fetched first
// the adds hit the cache. The values read are discarded: stale values are harmless.
// Bindings: 0 positions (float[3N]), 1 dL/dy (float rows of dy_stride); `_prefetch` also texel 12, the level's
//           chunk of the gradient array (R32, R32G32 or R32G32B32A32 SFLOAT for F = 1, 2, 4 and 8).
// Push:     grads (the level's chunk address, or the chunk table's address when HASH_CHUNKED), shift, param_offset
//           (first float of the level, in the chunk or in the array), n, dy_stride, dy_col (the level's first
//           column), scale, res, entries, weight (the level's coarse-to-fine weight, as in the forward: dL/dy is
//           multiplied by it, so a held-back level gets no gradient and issues no atomics); `_prefetch`: zero (0).
// Spec:     0 F, 1 HASHED, 2 HASH_CHUNKED, 3 VEC_DY (read width of dL/dy, floats).
// Threads:  one invocation per point, 64 per group, folded into 2D past 65535 groups.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "network/row_io.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(constant_id = 1) const uint HASHED = 1;
layout(constant_id = 2) const uint HASH_CHUNKED = 0;
layout(constant_id = 3) const uint VEC_DY = 1;
#include "encoding/hashgrid_entry.glsl"
layout(buffer_reference, std430, buffer_reference_align = 4) buffer HashGradF1 { float v[]; };
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
ROWS_DECLARE(1, dy, readonly)
layout(push_constant) uniform Push {
    uint64_t table; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; // table: the gradients
    float scale; uint res; uint entries; float weight;
#ifdef HASH_PREFETCH
    uint zero;
#endif
} pc;
#ifdef HASH_PREFETCH
layout(binding = 12) uniform samplerBuffer grad_texels;
#endif

void main() {
    uint row = global_index();
    if (row >= pc.n) return;
    float g[F];
    ROWS_LOAD(dy, VEC_DY, row * pc.dy_stride + pc.dy_col, g, 0u, F)
    [[unroll]] for (uint f = 0u; f < F; ++f) g[f] *= pc.weight;
    bool any_nonzero = false;
    [[unroll]] for (uint f = 0u; f < F; ++f) any_nonzero = any_nonzero || g[f] != 0.0;
    if (!any_nonzero) return; // masked-out samples cost no atomics
    HashLevel lv = HashLevel(pc.scale, pc.res, pc.entries, 0u, HASHED, 0u, 0u, 0u);
    vec3 p = vec3(pos[3u * row], pos[3u * row + 1u], pos[3u * row + 2u]);
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    uint es[8]; // the corners' first floats
    [[unroll]] for (uint c = 0u; c < 8u; ++c) {
        es[c] = pc.param_offset + hash_index_known(lv, corner_vertex(c, cell), HASHED != 0u) * F;
    }
#ifdef HASH_PREFETCH
    float touch = 0.0; // texel (F floats, or 4 of them for F = 8) holding each corner's first float
    [[unroll]] for (uint c = 0u; c < 8u; ++c) touch += texelFetch(grad_texels, int(es[c] / min(F, 4u))).x;
    uint dep = floatBitsToUint(touch) & pc.zero; // 0, known only at run time
#else
    uint dep = 0u;
#endif
    [[unroll]] for (uint c = 0u; c < 8u; ++c) {
        float w = corner_weight(c, frac);
        uint e = es[c] + dep;
        uint64_t a;
        uint o;
        hash_locate(pc.table, pc.shift, e, a, o);
        [[unroll]] for (uint f = 0u; f < F; ++f) atomicAdd(HashGradF1(a).v[o + f], w * g[f]);
    }
}
