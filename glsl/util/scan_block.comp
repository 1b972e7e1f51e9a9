// scan_block_{f32,u32}: exclusive prefix sum inside each block of 256 elements, and each block's total.
// output[i] = sum of input[256g .. i) for i in block g; block_sums[g] = sum of the whole block.
// The host scans block_sums recursively and adds them back with scan_add (src/ops/scan.rs).
// input and output may be the same buffer (each invocation reads its element before any write).
// Bindings: 0 input (VALUE[], read), 1 output (VALUE[], written), 2 block_sums (VALUE[ceil(n/256)], written).
// Push:     n.
// Threads:  256 per group, one element each; Hillis-Steele scan in shared memory (2 KiB shared).
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/value_type.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Input { VALUE input_values[]; };
layout(std430, binding = 1) writeonly buffer Output { VALUE output_values[]; };
layout(std430, binding = 2) writeonly buffer BlockSums { VALUE block_sums[]; };
layout(push_constant) uniform Push { uint n; } pc;

shared VALUE tile[2][256];

void main() {
    // Groups past the last block exist only because the grid was folded to 2D: the whole group leaves.
    if (group_index() * 256u >= pc.n) return;
    uint i = global_index();
    uint lid = gl_LocalInvocationID.x;
    tile[0][lid] = i < pc.n ? input_values[i] : VALUE_ZERO;
    barrier();
    uint src = 0u;
    for (uint offset = 1u; offset < 256u; offset <<= 1u) {
        VALUE v = tile[src][lid];
        if (lid >= offset) v += tile[src][lid - offset];
        tile[1u - src][lid] = v;
        src = 1u - src;
        barrier();
    }
    // tile[src] now holds the inclusive scan; shift it by one for the exclusive result.
    if (i < pc.n) output_values[i] = lid == 0u ? VALUE_ZERO : tile[src][lid - 1u];
    if (lid == 255u) block_sums[group_index()] = tile[src][255];
}
