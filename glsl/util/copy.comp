// copy_u32: dst[dst_offset + i] = src[src_offset + i] for i in [0, n). Copies any 32-bit type.
// Bindings: 0 src (uint[], read), 1 dst (uint[], written).
// Push:     n, src_offset, dst_offset.
// Threads:  one invocation per element, 256 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Src { uint src[]; };
layout(std430, binding = 1) writeonly buffer Dst { uint dst[]; };
layout(push_constant) uniform Push { uint n; uint src_offset; uint dst_offset; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    dst[pc.dst_offset + i] = src[pc.src_offset + i];
}
