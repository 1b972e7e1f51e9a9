// fill_u32: data[offset + i] = value for i in [0, n). Fills any 32-bit type (pass f32 bits for floats).
// Each invocation writes VEC consecutive elements in one store (row_io.glsl: on lavapipe a 32-byte store per lane
// costs about what a 4-byte one does); the host fills the 8-aligned body of a range with VEC = 8, the rest with 1.
// Bindings: 0 data (uint[], written).
// Push:     n (elements, a multiple of VEC), offset (a multiple of VEC), value.
// Spec:     0 VEC (8 or 1).
// Threads:  one invocation per VEC elements, 256 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint VEC = 1;
ROWS_DECLARE(0, data, writeonly)
layout(push_constant) uniform Push { uint n; uint offset; uint value; } pc;

void main() {
    uint i = global_index() * VEC;
    if (i >= pc.n) return;
    float v[VEC];
    [[unroll]] for (uint k = 0u; k < VEC; ++k) v[k] = uintBitsToFloat(pc.value);
    ROWS_STORE(data, VEC, pc.offset + i, v, 0u, VEC)
}
