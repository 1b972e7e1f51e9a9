// check_finite: flags a NaN or Inf anywhere in data[0..n]: flag[0] = 1 and flag[slot] = 1 if any element has an
// all-ones exponent (tested on the bits, so no compiler assumption about NaN can remove the test). Every writer writes
// the same value, so no atomics are needed; the caller zeroes the flags first. Twin: src/reference/util.rs
// `any_non_finite`. With GATED = 1 the kernel does nothing unless flag[0] is already set: the training step's guard
// checks the gradients and losses first, then its named buffers only when something was non-finite, so the first
// poisoned buffer is known without a second submission (src/nerf/guard.rs).
// No barriers and no shared memory: on lavapipe this reads 13 M floats in a few ms, where a tree reduction (the
// NaN guard's former sum) took 400 ms. Elements are read 8 at a time (row_io.glsl: on lavapipe a 32-byte read per
// lane costs about what a 4-byte one does); the last n % 8 one by one.
// Bindings: 0 data (float[n], bound from a 32-byte aligned offset), 1 flag (uint[slot + 1]: read when GATED, written
// only when something is non-finite).
// Push:     n, stride (total invocations: group of 8 elements g is read by invocation g % stride; coalesced on GPUs),
//           slot (the flag word that names this buffer; 0 for none).
// Spec:     GATED (0 or 1).
// Threads:  one invocation per `stride`-th group run, 256 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 256
#include "common/index.glsl"
#include "network/row_io.glsl"
layout(local_size_x = WG_SIZE) in;
ROWS_DECLARE(0, data, readonly)
layout(std430, binding = 1) buffer Flag { uint flag[]; };
layout(push_constant) uniform Push { uint n; uint stride; uint slot; } pc;
layout(constant_id = 0) const uint GATED = 0;

bool non_finite(float x) {
    return (floatBitsToUint(x) & 0x7f800000u) == 0x7f800000u;
}

void main() {
    uint i = global_index();
    if (i >= pc.stride) return;
    if (GATED != 0u && flag[0] == 0u) return;
    uint groups = pc.n / 8u;
    bool bad = false;
    for (uint g = i; g < groups && !bad; g += pc.stride) {
        float v[8];
        ROWS_LOAD(data, 8u, g * 8u, v, 0u, 8u)
        [[unroll]] for (uint k = 0u; k < 8u; ++k) bad = bad || non_finite(v[k]);
    }
    if (i == 0u) {
        for (uint k = groups * 8u; k < pc.n; ++k) bad = bad || non_finite(data_1[k]);
    }
    if (bad) {
        flag[0] = 1u;
        flag[pc.slot] = 1u;
    }
}
