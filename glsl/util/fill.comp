// fill_u32: data[offset + i] = value for i in [0, n). Fills any 32-bit type (pass f32 bits for floats).
// Bindings: 0 data (uint[], written).
// Push:     n, offset, value.
// Threads:  one invocation per element, 256 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) writeonly buffer Data { uint data[]; };
layout(push_constant) uniform Push { uint n; uint offset; uint value; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    data[pc.offset + i] = pc.value;
}
