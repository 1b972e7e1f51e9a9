// mlp_out_delta: the MLP's output deltas (dL/d pre-activation) from dL/dy and the forward output y:
// delta[j] = dL/dy[j] * act'(y[j]) for j < N_OUT, and 0 for N_OUT <= j < N_COLS (the columns later kernels read).
// Bindings: 0 y rows (y_stride, from y_col), 1 dL/dy rows (dy_stride, from dy_col), 2 deltas (rows of d_stride floats
//           from d_col, N_COLS written).
// Push:     n, y_stride, y_col, dy_stride, dy_col, d_stride, d_col.
// Spec:     0 N_OUT, 1 N_COLS, 2 ACT (0 none, 1 sigmoid, 2 exp, 3 ReLU), 3 VEC_D (delta store width, floats).
// Threads:  one invocation per row, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint N_OUT = 16;
layout(constant_id = 1) const uint N_COLS = 16;
layout(constant_id = 2) const uint ACT = 0;
layout(constant_id = 3) const uint VEC_D = 1;
#include "network/activation.glsl"
layout(std430, binding = 0) readonly buffer Y { float yv[]; };
layout(std430, binding = 1) readonly buffer DY { float dyv[]; };
ROWS_DECLARE(2, deltas, writeonly)
layout(push_constant) uniform Push {
    uint n; uint y_stride; uint y_col; uint dy_stride; uint dy_col; uint d_stride; uint d_col;
} pc;

void main() {
    uint row = global_index();
    if (row >= pc.n) return;
    float d[N_COLS];
    [[unroll]] for (uint j = 0u; j < N_COLS; ++j) {
        d[j] = 0.0;
        if (j < N_OUT) d[j] = dyv[row * pc.dy_stride + pc.dy_col + j] * out_activation_grad(yv[row * pc.y_stride + pc.y_col + j]);
    }
    ROWS_STORE(deltas, VEC_D, row * pc.d_stride + pc.d_col, d, 0u, N_COLS)
}
