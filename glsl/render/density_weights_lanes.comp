// density_weights_lanes: density_weights (same bindings, push constants and results within fp32 rounding) with the
// ray's samples spread over 32 lanes: on a GPU a 4096-ray pass is 4096 x 32 invocations instead of 4096 serial
// loops of n samples. Formulas: density_weights.comp. The running sum of sigma delta is a prefix sum per block of 32
// samples plus the blocks before (ray_lanes.glsl).
// Bindings: 0 edges (float[R][n+1]), 1 raw (rows of raw_stride, density at column 0), 2 weights (float[R][n], written),
//           3 origins, 4 directions (only read without contraction, to zero density outside the box).
// Push:     n_rays, n, near, far, raw_stride, density_scale, contraction.
// Threads:  one workgroup of 32 per ray (lane i takes samples i, i + 32, ...), folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_lanes.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/density_weights_io.glsl"

void main() {
    uint r = group_index();
    if (r >= pc.n_rays) return; // uniform over the workgroup
    uint lane = lane_index();
    uint e0 = r * (pc.n + 1u);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    float acc = 0.0; // sum of sigma delta over the blocks before
    for (uint b = 0u; b < pc.n; b += LANES) {
        uint i = b + lane;
        float tau = 0.0;
        if (i < pc.n) {
            float t0 = edge_to_t(edges[e0 + i], pc.near, pc.far);
            float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
            float raw_i = raw[(r * pc.n + i) * pc.raw_stride];
            float sigma = density_at(raw_i, pc.density_scale, o + d * (0.5 * (t0 + t1)), pc.contraction != 0u);
            tau = sigma * (t1 - t0);
        }
        float block;
        float before = acc + lanes_exclusive_add(tau, block);
        if (i < pc.n) {
            float w = exp(-before) * alpha_of(tau);
            weights[r * pc.n + i] = isnan(w) ? 0.0 : w;
        }
        acc += block;
    }
}
