// density_weights: volume-rendering weights of one sampling level from its raw densities (§2.10):
// sigma_i = scale * exp(raw_i), delta_i = t_{i+1} - t_i, T_i = exp(-sum_{j<i} sigma_j delta_j), w_i = T_i (1 - exp(-sigma_i delta_i)).
// Used for the proposal levels (their weights drive PDF resampling and the interlevel loss).
// Bindings: 0 edges (float[R][n+1]), 1 raw (rows of raw_stride, density at column 0), 2 weights (float[R][n], written),
//           3 origins, 4 directions (only read without contraction, to zero density outside the box).
// Push:     n_rays, n, near, far, raw_stride, density_scale, contraction.
// Threads:  one invocation per ray (serial over its samples), 32 per group (one warp: a 4096-ray pass spreads over
//           128 SMs, not 64), folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/density_weights_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    uint e0 = r * (pc.n + 1u);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    float t0 = edge_to_t(edges[e0], pc.near, pc.far);
    float acc = 0.0; // sum of sigma delta so far
    for (uint i = 0u; i < pc.n; ++i) {
        float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
        float raw_i = raw[(r * pc.n + i) * pc.raw_stride];
        float sigma = density_at(raw_i, pc.density_scale, o + d * (0.5 * (t0 + t1)), pc.contraction != 0u);
        float tau = sigma * (t1 - t0);
        float w = exp(-acc) * alpha_of(tau);
        weights[r * pc.n + i] = isnan(w) ? 0.0 : w;
        acc += tau;
        t0 = t1;
    }
}
