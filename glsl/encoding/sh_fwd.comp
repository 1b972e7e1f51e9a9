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
    float sh[SH_DIM];
    sh_eval(vec3(dirs[3u * i], dirs[3u * i + 1u], dirs[3u * i + 2u]), sh);
    uint o = i * pc.row_stride + pc.col;
    for (uint k = 0u; k < SH_DIM; ++k) out_values[o + k] = sh[k];
}
