// mlp_coop_wgrad: mlp_tile_wgrad's weight-gradient partials on tensor cores (VK_KHR_cooperative_matrix, fp16 x
// fp16 -> fp32): partial[s][j][k] = sum over the rows of split s of delta[row][j] * act_in[row][k], for a TJ x TK
// tile of the matrix; mlp_wgrad_reduce then sums the splits as for the other kernels.
// The workgroup stages RB = 32 rows at a time of the tile's deltas and inputs as fp16 in shared memory, each
// operand scaled by one power of two per staged block (its largest |value| into [2^13, 2^14): deltas of 1e-7 keep
// their precision instead of flushing to fp16 subnormals). A block's product goes to a scratch accumulator that is
// added, unscaled, to the tile's fp32 sum.
// Built only with the `shaderc-from-source` feature; twin: mlp_tile_wgrad and the f64 reference
// (tests/kernels/nn_mlp.rs).
// Bindings: 0 delta rows (d_stride, from d_col), 1 act_in rows (a_stride, from a_col), 2 partial
//           (float[splits][out_w][in_w], written).
// Push:     n, out_w, in_w, d_stride, d_col, a_stride, a_col, rows_per_split, splits, tiles_k (as mlp_tile_wgrad).
// Spec:     0 TJ (16, 32 or 64), 1 TK (16, 32 or 64), 2 HALF_A (1: act_in rows are fp16 pairs).
// Threads:  one workgroup of 128 (four subgroups of 32) per (tile, split), consecutive groups on consecutive splits
//           of one tile, folded into 2D past 65535 groups; the tile's (TJ / 16)(TK / 16) 16 x 16 fragments go
//           round-robin to the subgroups (at most 4 each); a fragment that overhangs out_w or in_w (the last
//           layer's out_w is n_output rounded to 4) is written through shared memory, element by element.
//           Shared memory: 13 KiB.
#version 460
#define WG_SIZE 128
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_KHR_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "common/index.glsl"
#include "network/coop_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint TJ = 64;
layout(constant_id = 1) const uint TK = 64;
layout(constant_id = 2) const uint HALF_A = 0;
const uint RB = 32u;
const uint DS = 64u + 8u; // row strides in halves (16-byte aligned rows, staggered banks)
const uint AS = 64u + 8u;

layout(std430, binding = 0) readonly buffer DBuf { float delta[]; };
layout(std430, binding = 1) readonly buffer ABuf { float act[]; };
layout(std430, binding = 2) writeonly buffer PBuf { float partial[]; };
layout(std430, binding = 1) readonly buffer ABufH { uint act_h[]; };

float load_act(uint i) { return HALF_A != 0u ? unpackHalf2x16(act_h[i / 2u])[i % 2u] : act[i]; }
layout(push_constant) uniform Push {
    uint n; uint out_w; uint in_w; uint d_stride; uint d_col; uint a_stride; uint a_col; uint rows_per_split;
    uint splits; uint tiles_k;
} pc;

shared float16_t d_s[RB * DS]; // d_s[r * DS + j] = delta[r0 + r][j0 + j] * d_scale
shared float16_t a_s[RB * AS]; // a_s[r * AS + k] = act[r0 + r][k0 + k] * a_scale
shared float sg_max[2][4];     // per subgroup: largest |delta|, |act| of the staged block
shared float edge[4 * 256];     // per subgroup: a fragment that overhangs the matrix (the last layer's out_w)

const uint LD = RB * TJ / WG_SIZE; // delta values each thread stages (4, 8 or 16)
const uint LA = RB * TK / WG_SIZE;

void main() {
    uint g = group_index();
    uint tile = g / pc.splits, split = g % pc.splits;
    uint j0 = (tile / pc.tiles_k) * TJ;
    uint k0 = (tile % pc.tiles_k) * TK;
    uint begin = split * pc.rows_per_split;
    uint end = min(begin + pc.rows_per_split, pc.n);
    uint tid = gl_LocalInvocationID.x;
    uint sg = gl_SubgroupID;
    const uint FJ = TJ / 16u, FK = TK / 16u, NF = FJ * FK;

    MAT_C acc[4];
    [[unroll]] for (uint f = 0u; f < 4u; ++f) acc[f] = MAT_C(0.0);
    for (uint r0 = begin; r0 < end; r0 += RB) {
        float dv[16], av[16];
        float dmax = 0.0, amax = 0.0;
        [[unroll]] for (uint q = 0u; q < LD; ++q) {
            uint e = tid + q * WG_SIZE;
            uint r = e / TJ, j = e % TJ;
            uint row = r0 + r, col = j0 + j;
            dv[q] = (row < end && col < pc.out_w) ? delta[row * pc.d_stride + pc.d_col + col] : 0.0;
            dmax = max(dmax, abs(dv[q]));
        }
        [[unroll]] for (uint q = 0u; q < LA; ++q) {
            uint e = tid + q * WG_SIZE;
            uint r = e / TK, k = e % TK;
            uint row = r0 + r, col = k0 + k;
            av[q] = (row < end && col < pc.in_w) ? load_act(row * pc.a_stride + pc.a_col + col) : 0.0;
            amax = max(amax, abs(av[q]));
        }
        dmax = subgroupMax(dmax);
        amax = subgroupMax(amax);
        if (subgroupElect()) {
            sg_max[0][sg] = dmax;
            sg_max[1][sg] = amax;
        }
        barrier();
        float ds = block_scale_for(max(max(sg_max[0][0], sg_max[0][1]), max(sg_max[0][2], sg_max[0][3])), 1.0);
        float as = block_scale_for(max(max(sg_max[1][0], sg_max[1][1]), max(sg_max[1][2], sg_max[1][3])), 1.0);
        [[unroll]] for (uint q = 0u; q < LD; ++q) {
            uint e = tid + q * WG_SIZE;
            d_s[(e / TJ) * DS + e % TJ] = float16_t(dv[q] * ds);
        }
        [[unroll]] for (uint q = 0u; q < LA; ++q) {
            uint e = tid + q * WG_SIZE;
            a_s[(e / TK) * AS + e % TK] = float16_t(av[q] * as);
        }
        barrier();
        float unscale = (1.0 / ds) * (1.0 / as); // each factor a power of two: no overflow of ds * as
        [[unroll]] for (uint i = 0u; i < 4u; ++i) {
            uint f = sg + 4u * i;
            if (f < NF) {
                uint fj = f / FK, fk = f % FK;
                MAT_C part = MAT_C(0.0);
                [[unroll]] for (uint kk = 0u; kk < RB; kk += 16u) {
                    MAT_A ma; // delta^T: (j, r) from d_s[r][j], column-major
                    MAT_B mb; // act: (r, k) from a_s[r][k], row-major
                    coopMatLoad(ma, d_s, kk * DS + 16u * fj, DS, gl_CooperativeMatrixLayoutColumnMajor);
                    coopMatLoad(mb, a_s, kk * AS + 16u * fk, AS, gl_CooperativeMatrixLayoutRowMajor);
                    part = coopMatMulAdd(ma, mb, part);
                }
                acc[i] = acc[i] + part * unscale;
            }
        }
        barrier();
    }
    uint base = split * pc.out_w * pc.in_w;
    [[unroll]] for (uint i = 0u; i < 4u; ++i) {
        uint f = sg + 4u * i;
        if (f < NF) {
            uint j = j0 + 16u * (f / FK), k = k0 + 16u * (f % FK);
            if (j + 16u <= pc.out_w && k + 16u <= pc.in_w) {
                coopMatStore(acc[i], partial, base + j * pc.in_w + k, pc.in_w, gl_CooperativeMatrixLayoutRowMajor);
            } else if (j < pc.out_w && k < pc.in_w) {
                coopMatStore(acc[i], edge, 256u * sg, 16, gl_CooperativeMatrixLayoutRowMajor);
                subgroupMemoryBarrierShared();
                subgroupBarrier();
                for (uint e = gl_SubgroupInvocationID; e < 256u; e += 32u) {
                    uint jj = j + e / 16u, kk = k + e % 16u;
                    if (jj < pc.out_w && kk < pc.in_w) partial[base + jj * pc.in_w + kk] = edge[256u * sg + e];
                }
                subgroupBarrier();
            }
        }
    }
}
