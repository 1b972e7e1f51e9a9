// mlp_layer_bwd: one dense layer's backward pass to its input, for a block of KB inputs of every row:
// d_in[k] = (sum_j W[j][k] d_out[j]) * mask[k], k < KB, where mask[k] = (act_in[k] > 0) (the ReLU that produced the
// layer's input; MASK = 1) or 1 (the network input's gradient; MASK = 0). W is row-major with rows of IN_W floats.
// Same shape as mlp_layer_fwd: one row per invocation, its OUT_W deltas in registers, weights read at constant
// offsets from a push-constant address (one broadcast load per SIMD multiply-add on lavapipe; vec4 reads, so IN_W and
// KB are multiples of 4 and w_addr is 16-byte aligned), fully unrolled, 8 inputs accumulated together; the host
// keeps OUT_W x KB under a budget.
// Bindings: 0 d_out rows (d_stride, OUT_W floats from d_col), 1 act_in rows (a_stride, KB floats from a_col; read
//           when MASK = 1), 2 d_in rows (out_stride, KB floats from out_col, written); the `_texel` variant (build.rs
//           defines MLP_TEXEL): 0 d_in rows, texels 12 and 13 d_out and act_in as R32G32B32A32 views of their
//           buffers (row_io.glsl's ROWS_LOAD_TEX; VEC_D, VEC_A and HALF_A unused; with MASK = 0, 13 is not read).
// Push:     w_addr (device address of W[0][k0], the block's first column), n, d_stride, d_col, a_stride, a_col,
//           out_stride, out_col.
// Spec:     0 OUT_W, 1 IN_W, 2 KB, 3 MASK, 4 VEC_D, 5 VEC_A, 6 VEC_OUT (access widths, in the rows' element type),
//           7 HALF_A (1: act_in rows are fp16, a_stride and a_col in halves).
// Threads:  one invocation per row, 64 per group, folded into 2D past 65535 groups; rows past n are not written.
#version 460
#define WG_SIZE 64
#extension GL_EXT_buffer_reference : require
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint OUT_W = 64;
layout(constant_id = 1) const uint IN_W = 64;
layout(constant_id = 2) const uint KB = 64;
layout(constant_id = 3) const uint MASK = 1;
#ifndef MLP_TEXEL // the texel variant reads fp32 texels: no access widths, no fp16 activations
layout(constant_id = 4) const uint VEC_D = 1;
layout(constant_id = 5) const uint VEC_A = 1;
layout(constant_id = 7) const uint HALF_A = 0;
#endif
layout(constant_id = 6) const uint VEC_OUT = 1;
const uint ACC = KB < 8u ? KB : 8u; // inputs accumulated together (independent add chains)

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Weights { vec4 v[]; };
#ifdef MLP_TEXEL
ROWS_DECLARE(0, din, writeonly)
layout(binding = 12) uniform samplerBuffer dout_tex;
layout(binding = 13) uniform samplerBuffer ain_tex;
#else
ROWS_DECLARE(0, dout, readonly)
ROWS_DECLARE(1, ain, readonly)
ROWS_DECLARE(2, din, writeonly)
#endif
layout(push_constant) uniform Push {
    uint64_t w_addr; uint n; uint d_stride; uint d_col; uint a_stride; uint a_col; uint out_stride; uint out_col;
} pc;

void main() {
    uint row = global_index();
    uint r = min(row, pc.n - 1u);
    Weights w = Weights(pc.w_addr);
    float d[OUT_W];
#ifdef MLP_TEXEL
    ROWS_LOAD_TEX(dout_tex, r * pc.d_stride + pc.d_col, d, 0u, OUT_W)
#else
    ROWS_LOAD(dout, VEC_D, r * pc.d_stride + pc.d_col, d, 0u, OUT_W)
#endif
    float g[KB];
    [[unroll]] for (uint k0 = 0u; k0 < KB; k0 += ACC) {
        float acc[ACC];
        [[unroll]] for (uint a = 0u; a < ACC; ++a) acc[a] = 0.0;
        [[unroll]] for (uint j = 0u; j < OUT_W; ++j) {
            [[unroll]] for (uint a = 0u; a < ACC; a += 4u) {
                if (k0 + a < KB) {
                    vec4 wv = w.v[(j * IN_W + k0 + a) / 4u];
                    [[unroll]] for (uint c = 0u; c < 4u; ++c) acc[a + c] = fma(wv[c], d[j], acc[a + c]);
                }
            }
        }
        [[unroll]] for (uint a = 0u; a < ACC; ++a) if (k0 + a < KB) g[k0 + a] = acc[a];
    }
    if (MASK != 0u) {
        float h[KB];
#ifdef MLP_TEXEL
        ROWS_LOAD_TEX(ain_tex, r * pc.a_stride + pc.a_col, h, 0u, KB)
#else
        ROWS_LOAD_X(HALF_A, ain, VEC_A, r * pc.a_stride + pc.a_col, h, 0u, KB)
#endif
        [[unroll]] for (uint k = 0u; k < KB; ++k) g[k] = h[k] > 0.0 ? g[k] : 0.0;
    }
    if (row < pc.n) ROWS_STORE(din, VEC_OUT, row * pc.out_stride + pc.out_col, g, 0u, KB)
}
