// mlp_fwd: fully fused MLP forward. Each invocation carries ROWS batch rows through every layer with the
// activations in private arrays; each weight is loaded once per ROWS rows (and broadcast across the subgroup, which
// is what makes the shape fast on lavapipe's 8-wide SIMD). With STORE = 1 (training) every hidden layer's
// post-ReLU activations are written for the backward pass; STORE = 0 (inference) keeps nothing.
// Bindings: 0 input (rows of in_stride, IN_PAD columns from in_col, padding included), 1 output (rows of out_stride,
//           n_out columns from out_col), 2 acts (float[N_HIDDEN][n][WIDTH], written when STORE = 1).
// Push:     params (chunk-table address), shift, w_offset (first weight; the weights never cross a chunk),
//           n, in_stride, in_col, out_stride, out_col, n_out.
// Spec:     0 WIDTH, 1 IN_PAD, 2 OUT_PAD, 3 N_HIDDEN, 4 OUT_ACT, 5 ROWS, 6 STORE.
// Threads:  one invocation per ROWS rows, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "network/mlp_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 6) const uint STORE = 0;
layout(std430, binding = 0) readonly buffer Input { float xin[]; };
layout(std430, binding = 1) writeonly buffer Output { float yout[]; };
layout(std430, binding = 2) writeonly buffer Acts { float acts[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint w_offset; uint n;
    uint in_stride; uint in_col; uint out_stride; uint out_col; uint n_out;
} pc;

float a[ROWS * MAXW];
float b[ROWS * MAXW];

void main() {
    uint row0 = global_index() * ROWS;
    if (row0 >= pc.n) return;
    LargeF32Chunk wp = LargeF32Chunk(large_chunk_addr(pc.params, pc.shift, pc.w_offset));
    uint w = large_offset(pc.shift, pc.w_offset);
    for (uint r = 0u; r < ROWS; ++r) {
        uint row = min(row0 + r, pc.n - 1u); // tail rows repeat the last row; they are never written
        for (uint k = 0u; k < IN_PAD; ++k) a[r * MAXW + k] = xin[row * pc.in_stride + pc.in_col + k];
    }
    uint in_w = IN_PAD;
    for (uint layer = 0u; layer <= N_HIDDEN; ++layer) {
        bool last = layer == N_HIDDEN;
        uint out_w = last ? OUT_PAD : WIDTH;
        for (uint j = 0u; j < out_w; ++j) {
            float acc[ROWS];
            for (uint r = 0u; r < ROWS; ++r) acc[r] = 0.0;
            for (uint k = 0u; k < in_w; ++k) {
                float wjk = wp.v[w + j * in_w + k];
                for (uint r = 0u; r < ROWS; ++r) acc[r] += wjk * a[r * MAXW + k];
            }
            for (uint r = 0u; r < ROWS; ++r) b[r * MAXW + j] = last ? out_activation(acc[r]) : max(acc[r], 0.0);
        }
        w += out_w * in_w;
        in_w = out_w;
        for (uint r = 0u; r < ROWS; ++r) {
            if (row0 + r >= pc.n) break;
            for (uint j = 0u; j < out_w; ++j) {
                float v = b[r * MAXW + j];
                a[r * MAXW + j] = v;
                if (last) {
                    if (j < pc.n_out) yout[(row0 + r) * pc.out_stride + pc.out_col + j] = v;
                } else if (STORE != 0u) {
                    acts[(layer * pc.n + row0 + r) * WIDTH + j] = v;
                }
            }
        }
    }
}
