// scan_add_{f32,u32}: adds each block's scanned offset to its elements: data[i] += offsets[i / 256].
// Second half of the multi-block exclusive scan (src/ops/scan.rs).
// Bindings: 0 data (VALUE[], read-write), 1 offsets (VALUE[ceil(n/256)], read).
// Push:     n.
// Threads:  one invocation per element, 256 per group (one group per block), folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/value_type.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) buffer Data { VALUE data[]; };
layout(std430, binding = 1) readonly buffer Offsets { VALUE offsets[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    data[i] += offsets[group_index()];
}
