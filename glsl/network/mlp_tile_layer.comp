// mlp_tile_layer: one dense layer, forward or backward, as a shared-memory tiled matrix product (the GPU path; the
// register-tile kernels mlp_layer_fwd/mlp_layer_bwd are lavapipe's). For a BM x BN tile of the result:
//   C[r][c] = epilogue(sum_t A[r][t] * W(t, c)),  W(t, c) = w[t * ws_t + c * ws_c]
// forward:  A = the layer's input rows, W(t, c) = W[c][t] (ws_t 1, ws_c IN_W), epilogue the activation ACT;
// backward: A = the layer's output deltas, W(t, c) = W[t][c] (ws_t IN_W, ws_c 1), epilogue the ReLU mask
//           (act_in[r][c] > 0) or none (the network input's gradient).
// The workgroup stages BK = 16 steps of t at a time in shared memory (A transposed, so each thread reads 4
// consecutive rows as one vec4) and every thread accumulates a 4 x 4 block of C in registers. Shared memory:
// 20 KiB (within lavapipe's 32 KiB and NVIDIA's 48 KiB).
// Register use is fixed (16 accumulators), whatever the layer's width, unlike the register tiles.
// Bindings: 0 A rows (a_stride, k_dim floats from a_col), 1 mask rows (m_stride, from m_col; read when EPI = 1),
//           2 C rows (c_stride, cols floats from c_col, written).
// Push:     w_addr (device address of W[0][0]), n, k_dim, cols, ws_t, ws_c, a_stride, a_col, m_stride, m_col,
//           c_stride, c_col, col_tiles (column tiles per row tile).
// Spec:     0 BN (columns per tile: 16, 32 or 64; BM = 4096 / BN rows), 1 EPI (0 activation, 1 ReLU mask, 2 none),
//           2 ACT (as activation.glsl), 3 HALF_A, 4 HALF_M, 5 HALF_C (1: those rows are fp16, two per 32-bit word,
//           strides and columns in halves; a fp16 C has even cols, c_stride and c_col).
// Threads:  one workgroup of 256 per tile, tiles row-major (col_tiles per row tile), folded into 2D past 65535
//           groups; thread t owns rows 4 (t / (BN / 4)) + 0..3 and columns 4 (t % (BN / 4)) + 0..3 of the tile.
#version 460
#define WG_SIZE 256
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint BN = 64;
layout(constant_id = 1) const uint EPI = 0;
layout(constant_id = 2) const uint ACT = 3;
layout(constant_id = 3) const uint HALF_A = 0;
layout(constant_id = 4) const uint HALF_M = 0;
layout(constant_id = 5) const uint HALF_C = 0;
#include "network/activation.glsl"
const uint BM = 4096u / BN;
const uint BK = 16u;
const uint THREADS_N = BN / 4u;

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Weights { float v[]; };
layout(std430, binding = 0) readonly buffer ABuf { float a[]; };
layout(std430, binding = 1) readonly buffer MBuf { float m[]; };
layout(std430, binding = 2) writeonly buffer CBuf { float c[]; };
layout(std430, binding = 0) readonly buffer ABufH { uint a_h[]; };
layout(std430, binding = 1) readonly buffer MBufH { uint m_h[]; };
layout(std430, binding = 2) writeonly buffer CBufH { uint c_h[]; };

// Element i of a row buffer stored as floats or, when half, as pairs of halves.
float load_a(uint i) { return HALF_A != 0u ? unpackHalf2x16(a_h[i / 2u])[i % 2u] : a[i]; }
float load_m(uint i) { return HALF_M != 0u ? unpackHalf2x16(m_h[i / 2u])[i % 2u] : m[i]; }
layout(push_constant) uniform Push {
    uint64_t w_addr; uint n; uint k_dim; uint cols; uint ws_t; uint ws_c; uint a_stride; uint a_col;
    uint m_stride; uint m_col; uint c_stride; uint c_col; uint col_tiles;
} pc;

// Sized for the largest tile shapes (BM 256, BN 64; shared arrays need constant sizes): 20 KiB.
shared vec4 a_tile[BK][64]; // a_tile[t][r / 4][r % 4] = A[row0 + r][t0 + t], r < BM
shared vec4 w_tile[BK][16]; // w_tile[t][c / 4][c % 4] = W(t0 + t, col0 + c), c < BN

void main() {
    uint tile = group_index();
    uint row0 = (tile / pc.col_tiles) * BM;
    uint col0 = (tile % pc.col_tiles) * BN;
    uint tid = gl_LocalInvocationID.x;
    uint tr = tid / THREADS_N, tc = tid % THREADS_N;
    Weights w = Weights(pc.w_addr);
    vec4 acc[4];
    [[unroll]] for (uint i = 0u; i < 4u; ++i) acc[i] = vec4(0.0);
    for (uint t0 = 0u; t0 < pc.k_dim; t0 += BK) {
        // Consecutive threads read consecutive t of one row (16 floats), then the next row.
        [[unroll]] for (uint i = 0u; i < BM * BK / WG_SIZE; ++i) {
            uint e = tid + i * WG_SIZE;
            uint r = e / BK, t = e % BK;
            uint row = row0 + r, tt = t0 + t;
            a_tile[t][r / 4u][r % 4u] = (row < pc.n && tt < pc.k_dim) ? load_a(row * pc.a_stride + pc.a_col + tt) : 0.0;
        }
        [[unroll]] for (uint i = 0u; i < BK * BN / WG_SIZE; ++i) {
            uint e = tid + i * WG_SIZE;
            uint t = e / BN, cc = e % BN;
            uint col = col0 + cc, tt = t0 + t;
            w_tile[t][cc / 4u][cc % 4u] = (col < pc.cols && tt < pc.k_dim) ? w.v[tt * pc.ws_t + col * pc.ws_c] : 0.0;
        }
        barrier();
        [[unroll]] for (uint t = 0u; t < BK; ++t) {
            vec4 av = a_tile[t][tr];
            vec4 wv = w_tile[t][tc];
            [[unroll]] for (uint i = 0u; i < 4u; ++i) acc[i] = fma(vec4(av[i]), wv, acc[i]);
        }
        barrier();
    }
    [[unroll]] for (uint i = 0u; i < 4u; ++i) {
        uint row = row0 + 4u * tr + i;
        if (row >= pc.n) break;
        float v[4];
        [[unroll]] for (uint j = 0u; j < 4u; ++j) {
            uint col = min(col0 + 4u * tc + j, pc.cols - 1u);
            v[j] = acc[i][j];
            if (EPI == 0u) v[j] = out_activation(v[j]);
            if (EPI == 1u && !(load_m(row * pc.m_stride + pc.m_col + col) > 0.0)) v[j] = 0.0;
        }
        uint at = row * pc.c_stride + pc.c_col + col0 + 4u * tc;
        [[unroll]] for (uint j = 0u; j < 4u; j += 2u) {
            uint col = col0 + 4u * tc + j;
            if (HALF_C != 0u) {
                if (col < pc.cols) c_h[(at + j) / 2u] = packHalf2x16(vec2(v[j], v[j + 1u]));
            } else {
                if (col < pc.cols) c[at + j] = v[j];
                if (col + 1u < pc.cols) c[at + j + 1u] = v[j + 1u];
            }
        }
    }
}
