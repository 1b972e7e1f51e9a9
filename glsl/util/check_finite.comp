// check_finite: flags a NaN or Inf anywhere in data[0..n]: flag[0] = 1 if any element has an all-ones exponent
// (tested on the bits, so no compiler assumption about NaN can remove the test). Every writer writes the same value,
// so no atomics are needed; the caller zeroes the flag first. Twin: src/reference/util.rs `any_non_finite`.
// No barriers and no shared memory: on lavapipe this reads 13 M floats in a few ms, where a tree reduction (the
// NaN guard's former sum) took 400 ms.
// Bindings: 0 data (float[n]), 1 flag (uint[1], written only when something is non-finite).
// Push:     n, stride (total invocations: element i is read by invocation i % stride; coalesced on GPUs).
// Threads:  one invocation per `stride`-th element run, 256 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Data { uint data[]; };
layout(std430, binding = 1) writeonly buffer Flag { uint flag[]; };
layout(push_constant) uniform Push { uint n; uint stride; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.stride) return;
    for (uint k = i; k < pc.n; k += pc.stride) {
        if ((data[k] & 0x7f800000u) == 0x7f800000u) {
            flag[0] = 1u;
            return;
        }
    }
}
