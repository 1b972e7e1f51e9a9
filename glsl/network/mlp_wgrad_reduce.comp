// mlp_wgrad_reduce: grad[g_offset + e] += sum over s of partial[s][e], in split order (deterministic).
// Bindings: 0 partial (float[splits][count]).
// Push:     grads (chunk-table address), shift, g_offset (the matrix never crosses a chunk), count, splits.
// Threads:  one invocation per matrix element, 256 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Partial { float partial[]; };
layout(push_constant) uniform Push { uint64_t grads; uint shift; uint g_offset; uint count; uint splits; uint pad; uint pad2; } pc;

void main() {
    uint e = global_index();
    if (e >= pc.count) return;
    float s = 0.0;
    for (uint k = 0u; k < pc.splits; ++k) s += partial[k * pc.count + e];
    LargeF32Chunk g = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, pc.g_offset));
    g.v[large_offset(pc.shift, pc.g_offset) + e] += s;
}
