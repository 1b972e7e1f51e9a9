// pose_ray_grad: per ray, the gradient with respect to its (corrected) origin and direction from one sampling level:
// for each sample i at t_i (interval midpoint along the unit direction), x_i = o + t_i d and dL/dx_i comes from the
// hash grid's input gradient dL/dh_i through the contraction (pose_common.glsl `hash_input_grad`):
//   g_o += sum_i dL/dx_i,   g_d += sum_i t_i dL/dx_i,
// and, on the NeRF level, the view-direction term sh_direction_grad(d, sum_i dL/dSH_i) from the colour MLP's input
// gradient. Part of camera pose refinement; twin: src/reference/pose.rs `ray_grad`.
// Bindings: 0 origins (float[3R]), 1 directions (float[3R], corrected), 2 edges (float[R(n+1)], s-space),
//           3 dL/dh (float[3Rn], hashgrid_bwd_input's output), 4 colour dL/dinput rows (stride dx_stride, SH in
//           columns 0..16; unused unless sh != 0), 5 per-ray gradient (float[6R]: g_o, g_d; written, or added to when
//           accumulate != 0).
// Push:     n_rays, n (samples per ray), near, far, contraction, accumulate, sh (SH columns that carry the
//           direction: 0 none, else the SH degree squared; the others are zero in the forward), dx_stride.
// Threads:  one invocation per ray (it loops over the ray's samples), 32 per group (one warp: a 4096-ray pass spreads
//           over 128 SMs, not 64), folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "encoding/sh_constants.glsl"
#include "encoding/sh_grad.glsl"
#include "pose/pose_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "pose/pose_ray_grad_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    bool contraction = pc.contraction != 0u;
    uint e0 = r * (pc.n + 1u);
    vec3 g_o = vec3(0.0), g_d = vec3(0.0);
    float t0 = edge_to_t(edges[e0], pc.near, pc.far);
    for (uint i = 0u; i < pc.n; ++i) {
        float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
        float tm = 0.5 * (t0 + t1);
        t0 = t1;
        uint s = r * pc.n + i;
        vec3 gh = vec3(dpos[3u * s], dpos[3u * s + 1u], dpos[3u * s + 2u]);
        if (gh == vec3(0.0)) continue;
        vec3 gx = hash_input_grad(o + tm * d, gh, contraction);
        g_o += gx;
        g_d += tm * gx;
    }
    if (pc.sh != 0u) {
        float g[16];
        for (uint k = 0u; k < 16u; ++k) g[k] = 0.0;
        for (uint i = 0u; i < pc.n; ++i) {
            uint row = (r * pc.n + i) * pc.dx_stride;
            for (uint k = 0u; k < min(pc.sh, 16u); ++k) g[k] += cdx[row + k];
        }
        g_d += sh_direction_grad(d, g);
    }
    if (pc.accumulate != 0u) {
        g_o += vec3(ray_grad[6u * r], ray_grad[6u * r + 1u], ray_grad[6u * r + 2u]);
        g_d += vec3(ray_grad[6u * r + 3u], ray_grad[6u * r + 4u], ray_grad[6u * r + 5u]);
    }
    for (uint k = 0u; k < 3u; ++k) {
        ray_grad[6u * r + k] = g_o[k];
        ray_grad[6u * r + 3u + k] = g_d[k];
    }
}
