// scan_segmented_{f32,u32}: exclusive prefix sum restarted at every segment (one segment = one ray's samples).
// For segment s covering [starts[s], starts[s+1]): output[j] = sum of values[starts[s] .. j), totals[s] = segment sum.
// Segments are short (NeRF: 48-256 samples per ray), so each invocation scans one segment serially, in order:
// the result is bit-identical to a sequential f32 loop.
// Bindings: 0 values (VALUE[], read), 1 starts (uint[n_segments + 1], read), 2 output (VALUE[], written),
//           3 totals (VALUE[n_segments], written).
// Push:     n_segments.
// Threads:  one invocation per segment, 64 per group, folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/value_type.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Values { VALUE values[]; };
layout(std430, binding = 1) readonly buffer Starts { uint starts[]; };
layout(std430, binding = 2) writeonly buffer Output { VALUE output_values[]; };
layout(std430, binding = 3) writeonly buffer Totals { VALUE totals[]; };
layout(push_constant) uniform Push { uint n_segments; } pc;

void main() {
    uint s = global_index();
    if (s >= pc.n_segments) return;
    VALUE acc = VALUE_ZERO;
    for (uint j = starts[s]; j < starts[s + 1u]; ++j) {
        output_values[j] = acc;
        acc += values[j];
    }
    totals[s] = acc;
}
