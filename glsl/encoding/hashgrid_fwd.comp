// hashgrid_fwd: one level of the multiresolution hash encoding forward: out[n, col + l*F + f] = sum over the 8
// corners of weight * theta[level l, corner entry, f]; the last level's dispatch also writes the PAD columns after
// its own, [col + L*F, col + L*F + PAD), with pad_value (zeros for the density MLP, ones for tcnn's bias quirk).
// One dispatch per level (tcnn's cache-friendly order: the level's table is what the whole dispatch reads) with the
// level's parameters in push constants, so on lavapipe they are read once for all invocations rather than once per
// lane; each corner's F features are read in one access (hashgrid_entry.glsl).
// Bindings: 0 positions (float[3N], in [0,1]^3), 1 output (float rows of out_stride); the `_texel` variant
//           (build.rs defines HASH_TEXEL) also texel 12, the level's chunk (hashgrid_entry.glsl).
// Push:     params (the level's chunk address, or the chunk table's address when HASH_CHUNKED), shift, param_offset
//           (first float of the level, in the chunk or in the array), n, out_stride, out_col (the level's first
//           column), pad_value, scale, res, entries, weight (the level's coarse-to-fine weight: 1 unless
//           `field.coarse_to_fine` holds the level back; its F values are multiplied by it).
// Spec:     0 F, 1 HASHED (CoherentPrime hash, else dense index), 2 HASH_CHUNKED, 3 PAD (padding columns written
//           after the level's F), 4 VEC_OUT (store width, floats).
// Threads:  one invocation per point, 64 per group, folded into 2D past 65535 groups; points past n are computed
//           on point n-1 and not written.
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
layout(constant_id = 3) const uint PAD = 0;
layout(constant_id = 4) const uint VEC_OUT = 1;
#include "encoding/hashgrid_entry.glsl"
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
ROWS_DECLARE(1, outv, writeonly)
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint param_offset; uint n; uint out_stride; uint out_col; float pad_value;
    float scale; uint res; uint entries; float weight;
} pc;

void main() {
    uint row = global_index();
    uint i = min(row, pc.n - 1u);
    HashLevel lv = HashLevel(pc.scale, pc.res, pc.entries, 0u, HASHED, 0u, 0u, 0u);
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    float y[F + PAD];
    [[unroll]] for (uint f = 0u; f < F; ++f) y[f] = 0.0;
    [[unroll]] for (uint c = 0u; c < 8u; ++c) {
        float w = corner_weight(c, frac);
        uint g = pc.param_offset + hash_index_known(lv, corner_vertex(c, cell), HASHED != 0u) * F;
        HASH_ACCUMULATE_ENTRY(pc.params, pc.shift, g, w, y)
    }
    [[unroll]] for (uint f = 0u; f < F; ++f) y[f] *= pc.weight;
    [[unroll]] for (uint k = F; k < F + PAD; ++k) y[k] = pc.pad_value;
    if (row < pc.n) ROWS_STORE(outv, VEC_OUT, row * pc.out_stride + pc.out_col, y, 0u, F + PAD)
}
