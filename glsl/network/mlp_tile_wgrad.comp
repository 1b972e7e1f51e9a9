// mlp_tile_wgrad: one matrix's weight gradient as a shared-memory tiled product, split over the batch (the GPU
// path; mlp_wgrad is lavapipe's): partial[s][j][k] = sum over the rows of split s of delta[row][j] * act_in[row][k],
// for a TJ x TK tile of the matrix. The workgroup stages 16 rows at a time of the tile's deltas and inputs in shared
// memory; every thread accumulates a 4 x 4 block in registers. mlp_wgrad_reduce then sums the splits in a fixed
// order (deterministic, no atomics). Shared memory: 20 KiB.
// Bindings: 0 delta rows (d_stride, from d_col), 1 act_in rows (a_stride, from a_col), 2 partial
//           (float[splits][out_w][in_w], written).
// Push:     n, out_w, in_w, d_stride, d_col, a_stride, a_col, rows_per_split, splits, tiles_k.
// Spec:     0 TJ (16, 32 or 64), 1 TK (16 to 256; TJ x TK <= 4096), 2 HALF_A (1: act_in rows are fp16, two per
//           32-bit word, a_stride and a_col in halves).
// Threads:  one workgroup of 256 per (tile, split), consecutive groups on consecutive splits of one tile, folded
//           into 2D past 65535 groups; thread t < (TJ / 4)(TK / 4) owns rows 4 (t / (TK / 4)) + 0..3 and columns
//           4 (t % (TK / 4)) + 0..3 of the tile, the others only help stage.
#version 460
#define WG_SIZE 256
#extension GL_EXT_control_flow_attributes : require
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint TJ = 64;
layout(constant_id = 1) const uint TK = 64;
layout(constant_id = 2) const uint HALF_A = 0;
const uint RB = 16u;
const uint THREADS_K = TK / 4u;

layout(std430, binding = 0) readonly buffer DBuf { float delta[]; };
layout(std430, binding = 1) readonly buffer ABuf { float act[]; };
layout(std430, binding = 2) writeonly buffer PBuf { float partial[]; };
layout(std430, binding = 1) readonly buffer ABufH { uint act_h[]; };

float load_act(uint i) { return HALF_A != 0u ? unpackHalf2x16(act_h[i / 2u])[i % 2u] : act[i]; }
layout(push_constant) uniform Push {
    uint n; uint out_w; uint in_w; uint d_stride; uint d_col; uint a_stride; uint a_col; uint rows_per_split;
    uint splits; uint tiles_k;
} pc;

// Sized for the largest tiles (TJ 64, TK 256; shared arrays need constant sizes): 20 KiB.
shared vec4 d_tile[RB][16];
shared vec4 a_tile[RB][64];

void main() {
    uint g = group_index();
    uint tile = g / pc.splits, split = g % pc.splits;
    uint j0 = (tile / pc.tiles_k) * TJ;
    uint k0 = (tile % pc.tiles_k) * TK;
    uint begin = split * pc.rows_per_split;
    uint end = min(begin + pc.rows_per_split, pc.n);
    uint tid = gl_LocalInvocationID.x;
    uint tj = tid / THREADS_K, tk = tid % THREADS_K;
    bool owns = tid < (TJ / 4u) * THREADS_K;
    vec4 acc[4];
    [[unroll]] for (uint i = 0u; i < 4u; ++i) acc[i] = vec4(0.0);
    for (uint r0 = begin; r0 < end; r0 += RB) {
        [[unroll]] for (uint q = 0u; q < RB * TJ / WG_SIZE; ++q) {
            uint e = tid + q * WG_SIZE;
            uint r = e / TJ, j = e % TJ;
            uint row = r0 + r, col = j0 + j;
            d_tile[r][j / 4u][j % 4u] = (row < end && col < pc.out_w) ? delta[row * pc.d_stride + pc.d_col + col] : 0.0;
        }
        [[unroll]] for (uint q = 0u; q < RB * TK / WG_SIZE; ++q) {
            uint e = tid + q * WG_SIZE;
            uint r = e / TK, k = e % TK;
            uint row = r0 + r, col = k0 + k;
            a_tile[r][k / 4u][k % 4u] = (row < end && col < pc.in_w) ? load_act(row * pc.a_stride + pc.a_col + col) : 0.0;
        }
        barrier();
        if (owns) {
            [[unroll]] for (uint r = 0u; r < RB; ++r) {
                vec4 dv = d_tile[r][tj];
                vec4 av = a_tile[r][tk];
                [[unroll]] for (uint i = 0u; i < 4u; ++i) acc[i] = fma(vec4(dv[i]), av, acc[i]);
            }
        }
        barrier();
    }
    if (!owns) return;
    uint base = split * pc.out_w * pc.in_w;
    [[unroll]] for (uint i = 0u; i < 4u; ++i) {
        uint j = j0 + 4u * tj + i;
        if (j >= pc.out_w) break;
        [[unroll]] for (uint c = 0u; c < 4u; ++c) {
            uint k = k0 + 4u * tk + c;
            if (k < pc.in_w) partial[base + j * pc.in_w + k] = acc[i][c];
        }
    }
}
