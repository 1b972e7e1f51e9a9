// mlp_layer_fwd: one dense layer of an MLP (no bias, tiny-cuda-nn semantics) for a block of JB outputs of every row:
// out[j] = act(sum_k W[j][k] in[k]), j < JB, with W the block's rows of the layer's row-major matrix.
// Each invocation owns one row. Its IN_W inputs are loaded once (row_io.glsl: as wide as their alignment allows) and
// stay in registers; the layer is fully unrolled and every weight is read at a constant offset from a push-constant
// address, so the read is the same for all invocations: on lavapipe one broadcast load feeding a SIMD multiply over
// 8 rows, on GPUs a uniform load. Weights are read as vec4 (lavapipe's shader front end takes time quadratic in the
// number of loads: 8x faster pipeline creation than float reads); IN_W is a multiple of 4 and w_addr 16-byte aligned. Outputs are accumulated 8 at a time (independent add chains). The host keeps
// IN_W x JB under a budget: lavapipe's compile time grows faster than linearly with unrolled code.
// Bindings: 0 input rows (in_stride, IN_W floats from in_col), 1 output rows (out_stride, JB floats from out_col);
//           the `_texel` variant (build.rs defines MLP_TEXEL): 0 output rows, texel 12 the input rows as an
//           R32G32B32A32 view of their buffer (row_io.glsl's ROWS_LOAD_TEX; VEC_IN and HALF_IN unused).
// Push:     w_addr (device address of the block's first weight W[j0][0]), n, in_stride, in_col, out_stride, out_col.
// Spec:     0 IN_W, 1 JB, 2 ACT (0 none, 1 sigmoid, 2 exp, 3 ReLU), 3 VEC_IN, 4 VEC_OUT (access widths, in the
//           rows' element type), 5 HALF_IN, 6 HALF_OUT (1: those rows are fp16, strides and columns in halves).
// Threads:  one invocation per row, 64 per group, folded into 2D past 65535 groups; rows past n are computed on
//           row n-1 and not written.
#version 460
#define WG_SIZE 64
#extension GL_EXT_buffer_reference : require
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint IN_W = 64;
layout(constant_id = 1) const uint JB = 64;
layout(constant_id = 2) const uint ACT = 3;
#ifndef MLP_TEXEL // the texel variant reads fp32 input texels: no access width, no fp16 input
layout(constant_id = 3) const uint VEC_IN = 1;
layout(constant_id = 5) const uint HALF_IN = 0;
#endif
layout(constant_id = 4) const uint VEC_OUT = 1;
layout(constant_id = 6) const uint HALF_OUT = 0;
#include "network/activation.glsl"
const uint ACC = JB < 8u ? JB : 8u; // outputs accumulated together (independent add chains)

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Weights { vec4 v[]; };
#ifdef MLP_TEXEL
ROWS_DECLARE(0, yout, writeonly)
layout(binding = 12) uniform samplerBuffer xin_tex;
#else
ROWS_DECLARE(0, xin, readonly)
ROWS_DECLARE(1, yout, writeonly)
#endif
layout(push_constant) uniform Push {
    uint64_t w_addr; uint n; uint in_stride; uint in_col; uint out_stride; uint out_col;
} pc;

void main() {
    uint row = global_index();
    Weights w = Weights(pc.w_addr);
    float x[IN_W];
#ifdef MLP_TEXEL
    ROWS_LOAD_TEX(xin_tex, min(row, pc.n - 1u) * pc.in_stride + pc.in_col, x, 0u, IN_W)
#else
    ROWS_LOAD_X(HALF_IN, xin, VEC_IN, min(row, pc.n - 1u) * pc.in_stride + pc.in_col, x, 0u, IN_W)
#endif
    float y[JB];
    [[unroll]] for (uint j0 = 0u; j0 < JB; j0 += ACC) {
        float acc[ACC];
        [[unroll]] for (uint a = 0u; a < ACC; ++a) acc[a] = 0.0;
        [[unroll]] for (uint k = 0u; k < IN_W; k += 4u) {
            [[unroll]] for (uint a = 0u; a < ACC; ++a) {
                if (j0 + a < JB) {
                    vec4 wv = w.v[((j0 + a) * IN_W + k) / 4u];
                    [[unroll]] for (uint c = 0u; c < 4u; ++c) acc[a] = fma(wv[c], x[k + c], acc[a]);
                }
            }
        }
        [[unroll]] for (uint a = 0u; a < ACC; ++a) if (j0 + a < JB) y[j0 + a] = out_activation(acc[a]);
    }
    if (row < pc.n) ROWS_STORE_X(HALF_OUT, yout, VEC_OUT, row * pc.out_stride + pc.out_col, y, 0u, JB)
}
