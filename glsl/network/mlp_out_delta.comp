// mlp_out_delta: the MLP's output deltas (dL/d pre-activation) from dL/dy and the forward output y:
// delta[j] = dL/dy[j] * act'(y[j]) for j < N_OUT, and 0 in the padding columns N_OUT <= j < OUT_PAD.
// Bindings: 0 y rows (y_stride, from y_col), 1 dL/dy rows (dy_stride, from dy_col), 2 deltas (rows of OUT_PAD
//           floats from d_col, written).
// Push:     n, y_stride, y_col, dy_stride, dy_col, d_col.
// Spec:     0 N_OUT, 1 OUT_PAD, 2 ACT (0 none, 1 sigmoid, 2 exp, 3 ReLU).
// Threads:  one invocation per row, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#extension GL_EXT_control_flow_attributes : require
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint N_OUT = 16;
layout(constant_id = 1) const uint OUT_PAD = 16;
layout(constant_id = 2) const uint ACT = 0;
#include "network/activation.glsl"
layout(std430, binding = 0) readonly buffer Y { float yv[]; };
layout(std430, binding = 1) readonly buffer DY { float dyv[]; };
layout(std430, binding = 2) writeonly buffer Deltas { float deltas[]; };
layout(push_constant) uniform Push { uint n; uint y_stride; uint y_col; uint dy_stride; uint dy_col; uint d_col; } pc;

void main() {
    uint row = global_index();
    if (row >= pc.n) return;
    [[unroll]] for (uint j = 0u; j < OUT_PAD; ++j) {
        float d = 0.0;
        if (j < N_OUT) d = dyv[row * pc.dy_stride + pc.dy_col + j] * out_activation_grad(yv[row * pc.y_stride + pc.y_col + j]);
        deltas[pc.d_col + row * OUT_PAD + j] = d;
    }
}
