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
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 1) readonly buffer DSh { float d_sh[]; };
layout(std430, binding = 2) buffer DDirs { float d_dirs[]; };
layout(push_constant) uniform Push { uint n; uint row_stride; uint col; uint accumulate; } pc;

void main() {
    uint i = global_index();
    if (i >= pc.n) return;
    float x = dirs[3u * i], y = dirs[3u * i + 1u], z = dirs[3u * i + 2u];
    float xy = x * y, xz = x * z, yz = y * z;
    float x2 = x * x, y2 = y * y, z2 = z * z;
    uint o = i * pc.row_stride + pc.col;
    float g[16];
    for (uint k = 0u; k < 16u; ++k) g[k] = d_sh[o + k];
    float a = 1.0 - 5.0 * z2;      // 1 - 5z^2
    float b = SH_3C9 * (y2 - x2);  // dY9/dy = dY15/dx
    float gx = g[3] * -SH_C1 + g[4] * (SH_C4 * y) + g[7] * (-SH_C4 * z) + g[8] * (SH_2C8 * x)
             + g[9] * (-SH_6C9 * xy) + g[10] * (SH_C10 * yz) + g[13] * (SH_C11 * a) + g[14] * (SH_2C14 * xz)
             + g[15] * b;
    float gy = g[1] * -SH_C1 + g[4] * (SH_C4 * x) + g[5] * (-SH_C4 * z) + g[8] * (-SH_2C8 * y) + g[9] * b
             + g[10] * (SH_C10 * xz) + g[11] * (SH_C11 * a) + g[14] * (-SH_2C14 * yz) + g[15] * (SH_6C9 * xy);
    float gz = g[2] * SH_C1 + g[5] * (-SH_C4 * y) + g[6] * (SH_2C6 * z) + g[7] * (-SH_C4 * x)
             + g[10] * (SH_C10 * xy) + g[11] * (-SH_10C11 * yz) + g[12] * (SH_C12 * (15.0 * z2 - 3.0))
             + g[13] * (-SH_10C11 * xz) + g[14] * (SH_C14 * (x2 - y2));
    vec3 gd = vec3(gx, gy, gz);
    if (pc.accumulate != 0u) gd += vec3(d_dirs[3u * i], d_dirs[3u * i + 1u], d_dirs[3u * i + 2u]);
    d_dirs[3u * i] = gd.x;
    d_dirs[3u * i + 1u] = gd.y;
    d_dirs[3u * i + 2u] = gd.z;
}
