// adam_step: one Adam step (torch.optim.Adam semantics, fp32) on elements [offset, offset + n) of one chunk of the
// parameter store (src/nn/adam.rs dispatches once per chunk range of a parameter group):
//   g = grad * grad_scale + weight_decay * p          (L2 added to the gradient; grad_scale undoes loss scaling)
//   m = beta1 * m + (1 - beta1) * g
//   v = beta2 * v + (1 - beta2) * g^2
//   p = p - step_size * m / (sqrt(v) / bc2_sqrt + eps)  with step_size = lr / (1 - beta1^t), bc2_sqrt = sqrt(1 - beta2^t)
// The host computes step_size, bc2_sqrt, 1 - beta1 and 1 - beta2 in f64 (as torch does in Python floats).
// Each invocation updates VEC consecutive elements, read and written VEC at a time (row_io.glsl: on lavapipe one
// 32-byte access per lane costs about what a float access costs); the host dispatches the range's multiple of VEC
// with VEC = 8 and the rest with VEC = 1.
// Bindings: 0 params (float[], read-write), 1 grads (float[], read), 2 m (float[], read-write),
//           3 v (float[], read-write); all four the same chunk of their LargeArray; 4 gate (uint[1], read when
//           GATED: a set flag (the training step's NaN/Inf guard) skips the update, so a step is skipped on the
//           device without the host waiting for the verdict).
// Push:     n (elements), offset (a multiple of VEC), step_size, bc2_sqrt, beta1, one_minus_beta1, beta2,
//           one_minus_beta2, eps, weight_decay, grad_scale (44 bytes).
// Spec:     0 VEC (8 or 1), 1 GATED (0 or 1).
// Threads:  one invocation per VEC elements, 64 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint VEC = 8;
layout(constant_id = 1) const uint GATED = 0;
ROWS_DECLARE(0, params, )
ROWS_DECLARE(1, grads, readonly)
ROWS_DECLARE(2, m1, )
ROWS_DECLARE(3, m2, )
layout(std430, binding = 4) readonly buffer Gate { uint gate[]; };
layout(push_constant) uniform Push {
    uint n;
    uint offset;
    float step_size;
    float bc2_sqrt;
    float beta1;
    float one_minus_beta1;
    float beta2;
    float one_minus_beta2;
    float eps;
    float weight_decay;
    float grad_scale;
} pc;

void main() {
    uint i = global_index() * VEC;
    if (i >= pc.n) return;
    if (GATED != 0u && gate[0] != 0u) return;
    uint j = pc.offset + i;
    float p[VEC], g[VEC], m[VEC], v[VEC];
    ROWS_LOAD(params, VEC, j, p, 0u, VEC)
    ROWS_LOAD(grads, VEC, j, g, 0u, VEC)
    ROWS_LOAD(m1, VEC, j, m, 0u, VEC)
    ROWS_LOAD(m2, VEC, j, v, 0u, VEC)
    [[unroll]] for (uint k = 0u; k < VEC; ++k) {
        float gk = g[k] * pc.grad_scale + pc.weight_decay * p[k];
        m[k] = pc.beta1 * m[k] + pc.one_minus_beta1 * gk;
        v[k] = pc.beta2 * v[k] + pc.one_minus_beta2 * (gk * gk);
        p[k] = p[k] - pc.step_size * (m[k] / (sqrt(v[k]) / pc.bc2_sqrt + pc.eps));
    }
    ROWS_STORE(m1, VEC, j, m, 0u, VEC)
    ROWS_STORE(m2, VEC, j, v, 0u, VEC)
    ROWS_STORE(params, VEC, j, p, 0u, VEC)
}
