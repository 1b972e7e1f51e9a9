// adam_step: one Adam step (torch.optim.Adam semantics, fp32) on elements [offset, offset + n) of one chunk of the
// parameter store (src/nn/adam.rs dispatches once per chunk range of a parameter group):
//   g = grad * grad_scale + weight_decay * p          (L2 added to the gradient; grad_scale undoes loss scaling)
//   m = beta1 * m + (1 - beta1) * g
//   v = beta2 * v + (1 - beta2) * g^2
//   p = p - step_size * m / (sqrt(v) / bc2_sqrt + eps)  with step_size = lr / (1 - beta1^t), bc2_sqrt = sqrt(1 - beta2^t)
// The host computes step_size, bc2_sqrt, 1 - beta1 and 1 - beta2 in f64 (as torch does in Python floats).
// Bindings: 0 params (float[], read-write), 1 grads (float[], read), 2 m (float[], read-write),
//           3 v (float[], read-write); all four the same chunk of their LargeArray.
// Push:     n, offset, step_size, bc2_sqrt, beta1, one_minus_beta1, beta2, one_minus_beta2, eps, weight_decay,
//           grad_scale (44 bytes).
// Threads:  one invocation per element, 256 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) buffer Params { float params[]; };
layout(std430, binding = 1) readonly buffer Grads { float grads[]; };
layout(std430, binding = 2) buffer M { float m1[]; };
layout(std430, binding = 3) buffer V { float m2[]; };
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
    uint i = global_index();
    if (i >= pc.n) return;
    uint j = pc.offset + i;
    float p = params[j];
    float g = grads[j] * pc.grad_scale + pc.weight_decay * p;
    float m = pc.beta1 * m1[j] + pc.one_minus_beta1 * g;
    float v = pc.beta2 * m2[j] + pc.one_minus_beta2 * (g * g);
    m1[j] = m;
    m2[j] = v;
    params[j] = p - pc.step_size * (m / (sqrt(v) / pc.bc2_sqrt + pc.eps));
}
