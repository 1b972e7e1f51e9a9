// reduce_sum_{f32,u32}: one pass of a sum reduction: partial[g] = sum of input[256g .. 256g+256).
// The host repeats passes until one value is left (src/ops/reduce.rs). Tree order is fixed, so results are
// deterministic for a given n. u32 sums wrap modulo 2^32.
// Bindings: 0 input (VALUE[], read), 1 partial (VALUE[ceil(n/256)], written).
// Push:     n.
// Threads:  256 per group, one input element each; shared-memory tree (1 KiB shared).
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/value_type.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Input { VALUE input_values[]; };
layout(std430, binding = 1) writeonly buffer Partial { VALUE partial[]; };
layout(push_constant) uniform Push { uint n; } pc;

shared VALUE tile[256];

void main() {
    // Groups past the last block exist only because the grid was folded to 2D: the whole group leaves.
    if (group_index() * 256u >= pc.n) return;
    uint i = global_index();
    uint lid = gl_LocalInvocationID.x;
    tile[lid] = i < pc.n ? input_values[i] : VALUE_ZERO;
    barrier();
    for (uint stride = 128u; stride > 0u; stride >>= 1u) {
        if (lid < stride) tile[lid] += tile[lid + stride];
        barrier();
    }
    if (lid == 0u) partial[group_index()] = tile[0];
}
