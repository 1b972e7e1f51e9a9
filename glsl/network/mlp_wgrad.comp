// mlp_wgrad: one matrix's weight gradient, split over the batch: partial[s][j][k] = sum over the rows of split s of
// delta[row][j] * act_in[row][k]. Each invocation owns a 4x4 tile of the matrix for one split (16 FMAs per 8 loads);
// mlp_wgrad_reduce then sums the splits in a fixed order, so the result is deterministic (no atomics).
// Bindings: 0 delta (rows of d_stride from d_col, out_w columns), 1 act_in (rows of a_stride from a_col, in_w columns),
//           2 partial (float[splits][out_w][in_w], written).
// Push:     n, out_w, in_w, d_stride, d_col, a_stride, a_col, rows_per_split, splits.
// Threads:  one invocation per (split, 4x4 tile), 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Delta { float delta[]; };
layout(std430, binding = 1) readonly buffer ActIn { float act_in[]; };
layout(std430, binding = 2) writeonly buffer Partial { float partial[]; };
layout(push_constant) uniform Push {
    uint n; uint out_w; uint in_w; uint d_stride; uint d_col; uint a_stride; uint a_col; uint rows_per_split; uint splits;
} pc;

void main() {
    uint inv = global_index();
    uint tiles_k = pc.in_w / 4u;
    uint tiles = (pc.out_w / 4u) * tiles_k;
    if (inv >= tiles * pc.splits) return;
    uint split = inv / tiles;
    uint tile = inv % tiles;
    uint j0 = (tile / tiles_k) * 4u;
    uint k0 = (tile % tiles_k) * 4u;
    uint begin = split * pc.rows_per_split;
    uint end = min(begin + pc.rows_per_split, pc.n);
    vec4 acc[4] = vec4[4](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));
    for (uint row = begin; row < end; ++row) {
        uint db = row * pc.d_stride + pc.d_col + j0;
        uint ab = row * pc.a_stride + pc.a_col + k0;
        vec4 av = vec4(act_in[ab], act_in[ab + 1u], act_in[ab + 2u], act_in[ab + 3u]);
        for (uint jj = 0u; jj < 4u; ++jj) acc[jj] += delta[db + jj] * av;
    }
    uint base = split * pc.out_w * pc.in_w;
    for (uint jj = 0u; jj < 4u; ++jj) {
        for (uint kk = 0u; kk < 4u; ++kk) partial[base + (j0 + jj) * pc.in_w + k0 + kk] = acc[jj][kk];
    }
}
