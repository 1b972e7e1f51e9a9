// mlp_wgrad_reduce: grad[g_offset + e] += sum over s of partial[s][e], in a fixed order (deterministic): group q of
// 8 sums the splits s = q, q + 8, q + 16, ... in order, then one invocation adds the 8 group sums in order q = 0..7.
// Splitting the sum over 8 groups puts 8x the invocations on a matrix: the proposal MLPs' small matrices (a few
// hundred weights, 256 splits) used to run as one or two workgroups, each invocation a serial loop of 256 loads,
// about 27 us per dispatch on an H100 whatever the rows, and a step in 4096-ray passes reduces once per pass.
// Bindings: 0 partial (float[splits][count]).
// Push:     grads (chunk-table address), shift, g_offset (the matrix never crosses a chunk), count, splits.
// Threads:  one workgroup of 256 per 32 matrix elements: invocation x takes element 32 * group + x % 32 and split
//           group x / 32 (a subgroup of 32 reads 32 consecutive floats per split); folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#define ELEMS 32u
#define GROUPS 8u
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Partial { float partial[]; };
layout(push_constant) uniform Push { uint64_t grads; uint shift; uint g_offset; uint count; uint splits; uint pad; uint pad2; } pc;

shared float group_sum[GROUPS][ELEMS];

void main() {
    uint x = gl_LocalInvocationID.x;
    uint el = x % ELEMS, q = x / ELEMS;
    uint e = group_index() * ELEMS + el;
    float s = 0.0;
    if (e < pc.count) {
        for (uint k = q; k < pc.splits; k += GROUPS) s += partial[k * pc.count + e];
    }
    group_sum[q][el] = s;
    barrier();
    if (q != 0u || e >= pc.count) return;
    float t = 0.0;
    for (uint g = 0u; g < GROUPS; ++g) t += group_sum[g][el];
    LargeF32Chunk gr = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, pc.g_offset));
    gr.v[large_offset(pc.shift, pc.g_offset) + e] += t;
}
