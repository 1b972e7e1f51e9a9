// pose_ray_grad_lanes: pose_ray_grad (same bindings, push constants and results within fp32 rounding) with a ray's
// samples spread over 32 lanes, for GPUs: lane l sums samples l, l + 32, ... of g_o, g_d and the SH columns, and
// the workgroup adds the lanes' sums (ray_lanes.glsl). Formulas: pose_ray_grad.comp; twin: src/reference/pose.rs
// `ray_grad`.
// Bindings: 0 origins (float[3R]), 1 directions (float[3R], corrected), 2 edges (float[R(n+1)], s-space),
//           3 dL/dh (float[3Rn]), 4 colour dL/dinput rows (stride dx_stride, SH in columns 0..16; unused unless
//           sh != 0), 5 per-ray gradient (float[6R]: g_o, g_d; written, or added to when accumulate != 0).
// Push:     n_rays, n, near, far, contraction, accumulate, sh, dx_stride.
// Threads:  one workgroup of 32 per ray, folded into 2D past 65535 groups; lane 0 writes the ray's gradient.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_lanes.glsl"
#include "encoding/sh_constants.glsl"
#include "encoding/sh_grad.glsl"
#include "pose/pose_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "pose/pose_ray_grad_io.glsl"

void main() {
    uint r = group_index();
    if (r >= pc.n_rays) return; // uniform over the workgroup
    uint lane = lane_index();
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    bool contraction = pc.contraction != 0u;
    uint e0 = r * (pc.n + 1u);
    vec3 g_o = vec3(0.0), g_d = vec3(0.0);
    for (uint i = lane; i < pc.n; i += LANES) {
        float t0 = edge_to_t(edges[e0 + i], pc.near, pc.far);
        float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
        float tm = 0.5 * (t0 + t1);
        uint s = r * pc.n + i;
        vec3 gh = vec3(dpos[3u * s], dpos[3u * s + 1u], dpos[3u * s + 2u]);
        if (gh == vec3(0.0)) continue;
        vec3 gx = hash_input_grad(o + tm * d, gh, contraction);
        g_o += gx;
        g_d += tm * gx;
    }
    for (uint k = 0u; k < 3u; ++k) {
        g_o[k] = lanes_add(g_o[k]);
        g_d[k] = lanes_add(g_d[k]);
    }
    if (pc.sh != 0u) {
        float g[16];
        uint sh = min(pc.sh, 16u);
        for (uint k = 0u; k < 16u; ++k) {
            float part = 0.0;
            if (k < sh) {
                for (uint i = lane; i < pc.n; i += LANES) part += cdx[(r * pc.n + i) * pc.dx_stride + k];
            }
            g[k] = lanes_add(part);
        }
        g_d += sh_direction_grad(d, g);
    }
    if (lane != 0u) return;
    if (pc.accumulate != 0u) {
        g_o += vec3(ray_grad[6u * r], ray_grad[6u * r + 1u], ray_grad[6u * r + 2u]);
        g_d += vec3(ray_grad[6u * r + 3u], ray_grad[6u * r + 4u], ray_grad[6u * r + 5u]);
    }
    for (uint k = 0u; k < 3u; ++k) {
        ray_grad[6u * r + k] = g_o[k];
        ray_grad[6u * r + 3u + k] = g_d[k];
    }
}
