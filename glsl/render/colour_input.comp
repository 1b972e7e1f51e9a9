// colour_input: assembles the colour MLP's input rows for every NeRF sample (spec/nerfacto.md §1.3, §2.9):
// [SH(direction) 16, values k >= sh_count zeroed | geometric features geo_dim (density MLP outputs 1..geo_dim) | appearance app_dim | 1.0 ...].
// The trailing 1.0 columns pad to in_pad and act as tiny-cuda-nn's learned first-layer bias.
// Bindings: 0 directions (float[3R]), 1 density rows (stride density_stride), 2 camera index per ray (uint[R]),
//           3 appearance embeddings (float[cameras][app_dim]; unused when app_dim = 0), 4 output rows (stride in_pad).
// Push:     n_samples (R * n), n (samples per ray), geo_dim, app_dim, in_pad, density_stride, app_mode
//           (0: embedding of the ray's camera, 1: the mean embedding given at row `mean_row`), mean_row,
//           sh_count (1, 4, 9 or 16: the SH degree squared).
// Threads:  one invocation per sample, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "encoding/sh_constants.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 1) readonly buffer Density { float density[]; };
layout(std430, binding = 2) readonly buffer CamIdx { uint cam_idx[]; };
layout(std430, binding = 3) readonly buffer Embeddings { float emb[]; };
layout(std430, binding = 4) writeonly buffer Rows { float rows[]; };
layout(push_constant) uniform Push {
    uint n_samples; uint n; uint geo_dim; uint app_dim; uint in_pad; uint density_stride; uint app_mode; uint mean_row;
    uint sh_count;
} pc;

void main() {
    uint s = global_index();
    if (s >= pc.n_samples) return;
    uint r = s / pc.n;
    float sh[SH_DIM];
    sh_eval(vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]), sh);
    uint o = s * pc.in_pad;
    for (uint k = 0u; k < SH_DIM; ++k) rows[o + k] = k < pc.sh_count ? sh[k] : 0.0;
    for (uint k = 0u; k < pc.geo_dim; ++k) rows[o + SH_DIM + k] = density[s * pc.density_stride + 1u + k];
    uint a0 = SH_DIM + pc.geo_dim;
    if (pc.app_dim > 0u) {
        uint e = (pc.app_mode == 0u ? cam_idx[r] : pc.mean_row) * pc.app_dim;
        for (uint k = 0u; k < pc.app_dim; ++k) rows[o + a0 + k] = emb[e + k];
    }
    for (uint k = a0 + pc.app_dim; k < pc.in_pad; ++k) rows[o + k] = 1.0;
}
