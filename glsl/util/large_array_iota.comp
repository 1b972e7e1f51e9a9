// large_array_iota: writes a per-index pattern into a chunked large array through its chunk table
// (common/large_array.glsl): array[i] = i * 2654435761 + seed. Used to check chunked addressing end to end.
// Bindings: none (buffer device address).
// Push:     table (uint64 address of the chunk table), n, shift (log2 elements per chunk), seed, pad (to 24 bytes).
// Threads:  one invocation per element, 256 per group, folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(push_constant) uniform Push { uint64_t table; uint n; uint shift; uint seed; uint pad; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    large_store_u32(pc.table, pc.shift, i, i * 2654435761u + pc.seed);
}
