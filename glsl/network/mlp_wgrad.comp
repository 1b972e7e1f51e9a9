// mlp_wgrad: one matrix's weight gradient, split over the batch: partial[s][j][k] = sum over the rows of split s of
// delta[row][j] * act_in[row][k], for the invocation's JT x KT tile of the matrix. The accumulators stay in registers
// (constant indices); each row's JT deltas and KT inputs are loaded as wide as their alignment allows (row_io.glsl).
// mlp_wgrad_reduce then sums the splits in a fixed order, so the result is deterministic (no atomics).
// Bindings: 0 delta rows (d_stride, from d_col), 1 act_in rows (a_stride, from a_col), 2 partial
//           (float[splits][out_w][in_w], written).
// Push:     n, out_w, in_w, d_stride, d_col, a_stride, a_col, rows_per_split, splits, tiles_k (in_w / KT).
// Spec:     0 JT, 1 KT (tile; they divide out_w and in_w), 2 VEC_D, 3 VEC_A, 4 VEC_P (access widths, floats),
//           5 ROWS (rows per loop iteration), 6 HALF_A (1: act_in rows are fp16, a_stride, a_col and VEC_A in
//           halves).
// Threads:  one invocation per (tile, split), consecutive invocations on consecutive splits of one tile, 64 per
//           group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint JT = 4;
layout(constant_id = 1) const uint KT = 4;
layout(constant_id = 2) const uint VEC_D = 1;
layout(constant_id = 3) const uint VEC_A = 1;
layout(constant_id = 4) const uint VEC_P = 1;
layout(constant_id = 5) const uint ROWS = 1;
layout(constant_id = 6) const uint HALF_A = 0;
ROWS_DECLARE(0, delta, readonly)
ROWS_DECLARE(1, act, readonly)
ROWS_DECLARE(2, partial, writeonly)
layout(push_constant) uniform Push {
    uint n; uint out_w; uint in_w; uint d_stride; uint d_col; uint a_stride; uint a_col; uint rows_per_split; uint splits;
    uint tiles_k;
} pc;

void main() {
    uint inv = global_index();
    uint tiles_k = pc.tiles_k;
    uint tiles = (pc.out_w / JT) * tiles_k;
    if (inv >= tiles * pc.splits) return;
    uint tile = inv / pc.splits;
    uint split = inv % pc.splits;
    uint j0 = (tile / tiles_k) * JT;
    uint k0 = (tile % tiles_k) * KT;
    uint begin = split * pc.rows_per_split;
    uint end = min(begin + pc.rows_per_split, pc.n);
    float acc[JT][KT];
    [[unroll]] for (uint j = 0u; j < JT; ++j) [[unroll]] for (uint k = 0u; k < KT; ++k) acc[j][k] = 0.0;
    for (uint row0 = begin; row0 < end; row0 += ROWS) {
        float d[ROWS][JT];
        float a[ROWS][KT];
        [[unroll]] for (uint r = 0u; r < ROWS; ++r) {
            uint row = min(row0 + r, end - 1u);
            ROWS_LOAD(delta, VEC_D, row * pc.d_stride + pc.d_col + j0, d[r], 0u, JT)
            ROWS_LOAD_X(HALF_A, act, VEC_A, row * pc.a_stride + pc.a_col + k0, a[r], 0u, KT)
            if (row0 + r >= end) [[unroll]] for (uint j = 0u; j < JT; ++j) d[r][j] = 0.0;
        }
        [[unroll]] for (uint j = 0u; j < JT; ++j) {
            [[unroll]] for (uint k = 0u; k < KT; ++k) {
                float s = acc[j][k];
                [[unroll]] for (uint r = 0u; r < ROWS; ++r) s = fma(d[r][j], a[r][k], s);
                acc[j][k] = s;
            }
        }
    }
    uint base = split * pc.out_w * pc.in_w + j0 * pc.in_w + k0;
    [[unroll]] for (uint j = 0u; j < JT; ++j) ROWS_STORE(partial, VEC_P, base + j * pc.in_w, acc[j], 0u, KT)
}
