// sh_fwd: degree-4 spherical-harmonics encoding (16 values, tiny-cuda-nn convention, nerfacto.md §2.16) of unit
// directions, written into rows of a wider matrix: out[i * row_stride + col + k] = Y_k(d_i), k < 16. Columns
// outside [col, col + 16) are not touched, so the encoding can fill part of an MLP input row.
// Bindings: 0 dirs (float[3n], read; d_i = dirs[3i .. 3i+3], unit length), 1 out (float[], written).
// Push:     n, row_stride, col.
// Threads:  one invocation per direction, 64 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "encoding/sh_constants.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 1) writeonly buffer Out { float out_values[]; };
layout(push_constant) uniform Push { uint n; uint row_stride; uint col; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    float x = dirs[3u * i], y = dirs[3u * i + 1u], z = dirs[3u * i + 2u];
    float xy = x * y, xz = x * z, yz = y * z;
    float x2 = x * x, y2 = y * y, z2 = z * z;
    uint o = i * pc.row_stride + pc.col;
    out_values[o + 0u] = SH_C0;
    out_values[o + 1u] = -SH_C1 * y;
    out_values[o + 2u] = SH_C1 * z;
    out_values[o + 3u] = -SH_C1 * x;
    out_values[o + 4u] = SH_C4 * xy;
    out_values[o + 5u] = -SH_C4 * yz;
    out_values[o + 6u] = SH_C6 * z2 - SH_C6B;
    out_values[o + 7u] = -SH_C4 * xz;
    out_values[o + 8u] = SH_C8 * (x2 - y2);
    out_values[o + 9u] = SH_C9 * y * (y2 - 3.0 * x2);
    out_values[o + 10u] = SH_C10 * xy * z;
    out_values[o + 11u] = SH_C11 * y * (1.0 - 5.0 * z2);
    out_values[o + 12u] = SH_C12 * z * (5.0 * z2 - 3.0);
    out_values[o + 13u] = SH_C11 * x * (1.0 - 5.0 * z2);
    out_values[o + 14u] = SH_C14 * z * (x2 - y2);
    out_values[o + 15u] = SH_C9 * x * (3.0 * y2 - x2);
}
