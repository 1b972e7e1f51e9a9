// mlp_bwd: fully fused MLP backward through the activations (the weight gradient is mlp_wgrad's job).
// From dL/dy: output delta d_out = dL/dy * act'(y) (zero in padding columns); then through each matrix transposed,
// masked by the stored ReLU activations, giving every hidden layer's delta (dL/d pre-activation); finally, when
// want_dx = 1, dL/dx = W_in^T delta_0 (the input gradient, e.g. into the hash encoding).
// Bindings: 0 y (forward output rows), 1 dL/dy (rows), 2 acts (float[N_HIDDEN][n][WIDTH] from mlp_fwd),
//           3 deltas (float[N_HIDDEN][n][WIDTH] hidden deltas, then float[n][OUT_PAD] output deltas; written),
//           4 dL/dx (rows of dx_stride, IN_PAD columns from dx_col; written when want_dx = 1).
// Push:     params, shift, w_offset, n, y_stride, y_col, dy_stride, dy_col, n_out, dx_stride, dx_col, want_dx.
// Spec:     0 WIDTH, 1 IN_PAD, 2 OUT_PAD, 3 N_HIDDEN, 4 OUT_ACT, 5 ROWS.
// Threads:  one invocation per ROWS rows, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "network/mlp_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Y { float yv[]; };
layout(std430, binding = 1) readonly buffer DY { float dyv[]; };
layout(std430, binding = 2) readonly buffer Acts { float acts[]; };
layout(std430, binding = 3) writeonly buffer Deltas { float deltas[]; };
layout(std430, binding = 4) writeonly buffer DX { float dxv[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint shift; uint w_offset; uint n;
    uint y_stride; uint y_col; uint dy_stride; uint dy_col; uint n_out;
    uint dx_stride; uint dx_col; uint want_dx; uint pad;
} pc;

float a[ROWS * MAXW];
float b[ROWS * MAXW];

void main() {
    uint row0 = global_index() * ROWS;
    if (row0 >= pc.n) return;
    LargeF32Chunk wp = LargeF32Chunk(large_chunk_addr(pc.params, pc.shift, pc.w_offset));
    uint w_base = large_offset(pc.shift, pc.w_offset);
    uint hidden_total = N_HIDDEN * pc.n * WIDTH;
    for (uint r = 0u; r < ROWS; ++r) {
        uint row = min(row0 + r, pc.n - 1u);
        for (uint j = 0u; j < OUT_PAD; ++j) {
            float d = 0.0;
            if (j < pc.n_out) {
                d = dyv[row * pc.dy_stride + pc.dy_col + j] * out_activation_grad(yv[row * pc.y_stride + pc.y_col + j]);
            }
            a[r * MAXW + j] = d;
            if (row0 + r < pc.n) deltas[hidden_total + (row0 + r) * OUT_PAD + j] = d;
        }
    }
    // Offset of matrix m: W_in is WIDTH x IN_PAD, hidden ones WIDTH x WIDTH, W_out OUT_PAD x WIDTH.
    uint out_w = OUT_PAD;
    for (uint m = N_HIDDEN; m >= 1u; --m) {
        uint w = w_base + WIDTH * IN_PAD + (m - 1u) * WIDTH * WIDTH;
        uint in_w = WIDTH;
        for (uint k = 0u; k < in_w; ++k) {
            float acc[ROWS];
            for (uint r = 0u; r < ROWS; ++r) acc[r] = 0.0;
            for (uint j = 0u; j < out_w; ++j) {
                float wjk = wp.v[w + j * in_w + k];
                for (uint r = 0u; r < ROWS; ++r) acc[r] += wjk * a[r * MAXW + j];
            }
            for (uint r = 0u; r < ROWS; ++r) {
                uint row = min(row0 + r, pc.n - 1u);
                float h = acts[((m - 1u) * pc.n + row) * WIDTH + k];
                b[r * MAXW + k] = h > 0.0 ? acc[r] : 0.0;
            }
        }
        for (uint r = 0u; r < ROWS; ++r) {
            for (uint k = 0u; k < WIDTH; ++k) {
                a[r * MAXW + k] = b[r * MAXW + k];
                if (row0 + r < pc.n) deltas[((m - 1u) * pc.n + row0 + r) * WIDTH + k] = b[r * MAXW + k];
            }
        }
        out_w = WIDTH;
    }
    if (pc.want_dx == 0u) return;
    for (uint k = 0u; k < IN_PAD; ++k) {
        float acc[ROWS];
        for (uint r = 0u; r < ROWS; ++r) acc[r] = 0.0;
        for (uint j = 0u; j < WIDTH; ++j) {
            float wjk = wp.v[w_base + j * IN_PAD + k];
            for (uint r = 0u; r < ROWS; ++r) acc[r] += wjk * a[r * MAXW + j];
        }
        for (uint r = 0u; r < ROWS; ++r) {
            if (row0 + r < pc.n) dxv[(row0 + r) * pc.dx_stride + pc.dx_col + k] = acc[r];
        }
    }
}
