// sh_bwd: gradient of the degree-4 SH encoding (sh_fwd) with respect to the direction, for pose refinement through
// view directions: d_dirs[3i + j] (+)= sum_k d_sh[i * row_stride + col + k] * dY_k/dd_j (d_i). The partials are
// those of the polynomials as written (x, y, z independent, no projection onto the sphere).
// Bindings: 0 dirs (float[3n], read), 1 d_sh (float[], read; rows as in sh_fwd), 2 d_dirs (float[3n], written,
//           or read-modify-written when accumulate != 0).
// Push:     n, row_stride, col, accumulate (0: overwrite, else add).
// Threads:  one invocation per direction, 64 per group, 1D folded to 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "encoding/sh_constants.glsl"
#include "encoding/sh_grad.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 1) readonly buffer DSh { float d_sh[]; };
layout(std430, binding = 2) buffer DDirs { float d_dirs[]; };
layout(push_constant) uniform Push { uint n; uint row_stride; uint col; uint accumulate; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    vec3 d = vec3(dirs[3u * i], dirs[3u * i + 1u], dirs[3u * i + 2u]);
    uint o = i * pc.row_stride + pc.col;
    float g[SH_DIM];
    for (uint k = 0u; k < SH_DIM; ++k) g[k] = d_sh[o + k];
    vec3 gd = sh_direction_grad(d, g);
    if (pc.accumulate != 0u) gd += vec3(d_dirs[3u * i], d_dirs[3u * i + 1u], d_dirs[3u * i + 2u]);
    d_dirs[3u * i] = gd.x;
    d_dirs[3u * i + 1u] = gd.y;
    d_dirs[3u * i + 2u] = gd.z;
}
