// hashgrid_fwd: the multiresolution hash encoding forward: out[n, col + l*F + f] = sum over the 8 corners of
// weight * theta[level l, corner entry, f]; the last level also writes the PAD columns after its own,
// [col + L*F, col + L*F + PAD), with pad_value (zeros for the density MLP, ones for tcnn's bias quirk).
// Two dispatch shapes (src/nn/hashgrid.rs):
// - per level (the default on CPU devices): one dispatch per level (tcnn's cache-friendly order: the level's table
//   is what the whole dispatch reads) with the level's parameters in push constants, so on lavapipe they are read
//   once for all invocations rather than once per lane;
// - `_levels` (build.rs defines HASH_LEVELS; the default on GPUs): one dispatch for all levels, z over levels as
//   tcnn's blockIdx.y, each level's table read from the levels buffer. A GPU then runs every level at once instead
//   of a partial wave per level.
// Each corner's F features are read in one access (hashgrid_entry.glsl).
// Bindings: 0 positions (float[3N], in [0,1]^3), 1 output (float rows of out_stride); the `_texel` variant
//           (build.rs defines HASH_TEXEL) also texel 12, the level's chunk (hashgrid_entry.glsl); the `_levels`
//           variant also 2, the levels (HashLevel[L]).
// Push:     params (the chunk address, or the chunk table's address when HASH_CHUNKED), shift, param_offset (first
//           float of the level, or of the grid for `_levels`, in the chunk or in the array), n, out_stride, out_col
//           (the level's first column, or the grid's), pad_value; per level: scale, res, entries, weight (the
//           level's coarse-to-fine weight: 1 unless `field.coarse_to_fine` holds the level back; its F values are
//           multiplied by it); `_levels`: active_levels (level l's weight is clamp(active_levels - l, 0, 1)).
// Spec:     0 F, 1 HASHED (CoherentPrime hash, else dense index; per level only: `_levels` reads it per level),
//           2 HASH_CHUNKED, 3 PAD (padding columns written after the last level's F), 4 VEC_OUT (store width, floats).
// Threads:  one invocation per point (and level: z), 64 per group, folded into 2D past 65535 groups; points past n
//           are computed on point n-1 and not written.
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
layout(constant_id = 3) const uint PAD = 0;
layout(constant_id = 4) const uint VEC_OUT = 1;
#include "encoding/hashgrid_entry.glsl"
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
ROWS_DECLARE(1, outv, writeonly)
#ifdef HASH_LEVELS
#ifdef HASH_TEXEL
#error "the all-levels variant reads through device addresses"
#endif
layout(std430, binding = 2) readonly buffer Levels { HashLevel levels[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint param_offset; uint n; uint out_stride; uint out_col; float pad_value;
    float active_levels;
} pc;
#else
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint param_offset; uint n; uint out_stride; uint out_col; float pad_value;
    float scale; uint res; uint entries; float weight;
} pc;
#endif

void main() {
    uint row = global_index();
    uint i = min(row, pc.n - 1u);
#ifdef HASH_LEVELS
    uint l = gl_WorkGroupID.z;
    HashLevel lv = levels[l];
    bool hashed = lv.hashed != 0u;
    uint first = pc.param_offset + lv.offset * F;
    uint col = pc.out_col + l * F;
    float weight = clamp(pc.active_levels - float(l), 0.0, 1.0);
    bool last = l + 1u == gl_NumWorkGroups.z;
#else
    HashLevel lv = HashLevel(pc.scale, pc.res, pc.entries, 0u, HASHED, 0u, 0u, 0u);
    bool hashed = HASHED != 0u;
    uint first = pc.param_offset;
    uint col = pc.out_col;
    float weight = pc.weight;
    bool last = true; // the host sets PAD on the last level's dispatch only
#endif
    vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
    uvec3 cell;
    vec3 frac;
    hash_cell(lv, p, cell, frac);
    float y[F + PAD];
    [[unroll]] for (uint f = 0u; f < F; ++f) y[f] = 0.0;
    [[unroll]] for (uint c = 0u; c < 8u; ++c) {
        float w = corner_weight(c, frac);
        uint g = first + hash_index_known(lv, corner_vertex(c, cell), hashed) * F;
        HASH_ACCUMULATE_ENTRY(pc.params, pc.shift, g, w, y)
    }
    [[unroll]] for (uint f = 0u; f < F; ++f) y[f] *= weight;
    [[unroll]] for (uint k = F; k < F + PAD; ++k) y[k] = pc.pad_value;
    if (row < pc.n) {
        if (last) {
            ROWS_STORE(outv, VEC_OUT, row * pc.out_stride + col, y, 0u, F + PAD)
        } else {
            ROWS_STORE(outv, VEC_OUT, row * pc.out_stride + col, y, 0u, F)
        }
    }
}
