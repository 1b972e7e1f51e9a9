// mlp_coop_layer: mlp_tile_layer's product on tensor cores (VK_KHR_cooperative_matrix: 16 x 16 x 16 fp16 x fp16
// products accumulated in fp32). Same bindings, push constants, spec constants and result as mlp_tile_layer:
//   C[r][c] = epilogue(sum_t A[r][t] * W(t, c)),  W(t, c) = w[t * ws_t + c * ws_c]
// Operands go to fp16 in shared memory; the sums stay fp32. So that small deltas (the backward's A rows, often
// 1e-7..1e-4) keep their 11 significant bits instead of flushing to fp16 subnormals, each 64 x 32 block of A is
// scaled by a power of two bringing its largest |value| into [2^13, 2^14) (exact, undone on the fp32 sums; one scale
// per block, found from the values the threads hold anyway: no second read). Weights are converted as they are
// (|w| << 65504).
// Built only with the `shaderc-from-source` feature (Debian 12's glslang predates the extension); chosen at run
// time when the device offers fp16 16x16x16 subgroup matrices with fp32 accumulators and 32-wide subgroups
// (MlpTiling::coop_layers); its twin is mlp_tile_layer and the f64 reference (tests/kernels/nn_mlp.rs).
// Bindings: 0 A rows, 1 mask rows, 2 C rows (as mlp_tile_layer).
// Push:     w_addr, n, k_dim, cols, ws_t, ws_c, a_stride, a_col, m_stride, m_col, c_stride, c_col, col_tiles.
// Spec:     0 BN (16, 32 or 64 columns per tile; BM = 64 rows), 1 EPI, 2 ACT, 3 HALF_A, 4 HALF_M, 5 HALF_C.
// Threads:  one workgroup of 128 (four subgroups of 32) per 64 x BN tile, tiles row-major (col_tiles per row
//           tile), folded into 2D past 65535 groups; subgroup s owns rows 16 s .. 16 s + 15 of the tile and its
//           BN / 16 accumulators; every thread stages 16 A values and up to 16 weights per 32-deep block; each
//           subgroup passes its fragments through its own 1 KiB of shared memory for the epilogue (positions for
//           the mask and the bounds), two adjacent results per lane and step. Shared memory: 14 KiB (many
//           workgroups per SM: the kernel waits on memory, not on the tensor cores).
#version 460
#define WG_SIZE 128
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#extension GL_KHR_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint BN = 64;
layout(constant_id = 1) const uint EPI = 0;
layout(constant_id = 2) const uint ACT = 3;
layout(constant_id = 3) const uint HALF_A = 0;
layout(constant_id = 4) const uint HALF_M = 0;
layout(constant_id = 5) const uint HALF_C = 0;
#include "network/activation.glsl"
#include "network/coop_common.glsl"
const uint BM = 64u;
const uint BK = 32u;
const uint AS = BK + 8u;  // a_s row stride in halves (80 bytes: rows stay 16-byte aligned, banks staggered)
const uint WS = 64u + 8u; // w_s row stride in halves, sized for BN = 64

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Weights { float v[]; };
layout(std430, binding = 0) readonly buffer ABuf { float a[]; };
layout(std430, binding = 1) readonly buffer MBuf { float m[]; };
layout(std430, binding = 2) writeonly buffer CBuf { float c[]; };
layout(std430, binding = 0) readonly buffer ABufH { uint a_h[]; };
layout(std430, binding = 1) readonly buffer MBufH { uint m_h[]; };
layout(std430, binding = 2) writeonly buffer CBufH { uint c_h[]; };

float load_a(uint i) { return HALF_A != 0u ? unpackHalf2x16(a_h[i / 2u])[i % 2u] : a[i]; }
float load_m(uint i) { return HALF_M != 0u ? unpackHalf2x16(m_h[i / 2u])[i % 2u] : m[i]; }
layout(push_constant) uniform Push {
    uint64_t w_addr; uint n; uint k_dim; uint cols; uint ws_t; uint ws_c; uint a_stride; uint a_col;
    uint m_stride; uint m_col; uint c_stride; uint c_col; uint col_tiles;
} pc;

shared float16_t a_s[BM * AS];  // a_s[r * AS + t] = A[row0 + r][t0 + t] * scale (this block's)
shared float16_t w_s[BK * WS];  // w_s[t * WS + c] = W(t0 + t, col0 + c)
shared float frag[4 * 256];     // per subgroup: one 16 x 16 fragment of sums on its way through the epilogue
shared float sg_max[4];         // per subgroup: largest |A| of the block it staged

const uint LA = BM * BK / WG_SIZE; // A values each thread stages per block (16)

void main() {
    uint tile = group_index();
    uint row0 = (tile / pc.col_tiles) * BM;
    uint col0 = (tile % pc.col_tiles) * BN;
    uint tid = gl_LocalInvocationID.x;
    uint sg = gl_SubgroupID;
    Weights w = Weights(pc.w_addr);

    // The sums are kept in units of the current block's scale: when the next block's scale differs, the
    // accumulators are multiplied by the ratio (a power of two: exact).
    MAT_C acc[4];
    [[unroll]] for (uint j = 0u; j < 4u; ++j) acc[j] = MAT_C(0.0);
    float scale = 1.0;
    for (uint t0 = 0u; t0 < pc.k_dim; t0 += BK) {
        // A into registers (consecutive threads read consecutive t of one row), and its largest magnitude.
        float av[LA];
        float mx = 0.0;
        [[unroll]] for (uint q = 0u; q < LA; ++q) {
            uint e = tid + q * WG_SIZE;
            uint r = e / BK, t = e % BK;
            uint row = row0 + r, tt = t0 + t;
            av[q] = (row < pc.n && tt < pc.k_dim) ? load_a(row * pc.a_stride + pc.a_col + tt) : 0.0;
            mx = max(mx, abs(av[q]));
        }
        mx = subgroupMax(mx);
        if (subgroupElect()) sg_max[sg] = mx;
        // W: consecutive threads along whichever index is contiguous in memory.
        for (uint e = tid; e < BK * BN; e += WG_SIZE) {
            uint t, cc;
            if (pc.ws_t == 1u) {
                t = e % BK;
                cc = e / BK;
            } else {
                t = e / BN;
                cc = e % BN;
            }
            uint col = col0 + cc, tt = t0 + t;
            float v = (col < pc.cols && tt < pc.k_dim) ? w.v[tt * pc.ws_t + col * pc.ws_c] : 0.0;
            w_s[t * WS + cc] = float16_t(v);
        }
        barrier();
        // A block of zeros keeps the current scale: the accumulators keep their units.
        float s = block_scale_for(max(max(sg_max[0], sg_max[1]), max(sg_max[2], sg_max[3])), scale);
        [[unroll]] for (uint q = 0u; q < LA; ++q) {
            uint e = tid + q * WG_SIZE;
            a_s[(e / BK) * AS + e % BK] = float16_t(av[q] * s);
        }
        if (s != scale) {
            float ratio = s / scale;
            [[unroll]] for (uint j = 0u; j < 4u; ++j) acc[j] = acc[j] * ratio;
            scale = s;
        }
        barrier();
        [[unroll]] for (uint kk = 0u; kk < BK; kk += 16u) {
            MAT_A ma;
            coopMatLoad(ma, a_s, (16u * sg) * AS + kk, AS, gl_CooperativeMatrixLayoutRowMajor);
            [[unroll]] for (uint j = 0u; j < 4u; ++j) {
                if (16u * j < BN) {
                    MAT_B mb;
                    coopMatLoad(mb, w_s, kk * WS + 16u * j, WS, gl_CooperativeMatrixLayoutRowMajor);
                    acc[j] = coopMatMulAdd(ma, mb, acc[j]);
                }
            }
        }
        barrier();
    }
    float unscale = 1.0 / scale;
    // Epilogue, fragment by fragment through the subgroup's own staging area (no workgroup barrier): two adjacent
    // columns per lane and step (a fp16 C stores them as one word).
    uint lane = gl_SubgroupInvocationID;
    [[unroll]] for (uint j = 0u; j < 4u; ++j) {
        if (16u * j >= BN) continue;
        coopMatStore(acc[j], frag, 256u * sg, 16u, gl_CooperativeMatrixLayoutRowMajor);
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        for (uint e = lane; e < 128u; e += 32u) {
            uint r = e / 8u, cc = 2u * (e % 8u);
            uint row = row0 + 16u * sg + r, col = col0 + 16u * j + cc;
            if (row >= pc.n || col >= pc.cols) continue;
            float v[2];
            [[unroll]] for (uint q = 0u; q < 2u; ++q) {
                uint cq = min(col + q, pc.cols - 1u);
                v[q] = frag[256u * sg + 16u * r + cc + q] * unscale;
                if (EPI == 0u) v[q] = out_activation(v[q]);
                if (EPI == 1u && !(load_m(row * pc.m_stride + pc.m_col + cq) > 0.0)) v[q] = 0.0;
            }
            uint at = row * pc.c_stride + pc.c_col + col;
            if (HALF_C != 0u) {
                c_h[at / 2u] = packHalf2x16(vec2(v[0], v[1]));
            } else {
                c[at] = v[0];
                if (col + 1u < pc.cols) c[at + 1u] = v[1];
            }
        }
        subgroupBarrier();
    }
}
