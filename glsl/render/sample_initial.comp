// sample_initial: the piecewise initial sampler (spec/nerfacto.md §2.6). Per ray n + 1 edges in normalised spacing
// s_k = k/n, jittered in training with one uniform per ray (single jitter: edge_k = lower_k + u (upper_k - lower_k),
// lower/upper the midpoints to the neighbouring edges), unjittered in evaluation; then the hash-grid inputs of the n
// interval midpoints (contracted).
// Bindings: 0 origins (float[3R]), 1 directions (float[3R]), 2 edges (float[R][n+1], written),
//           3 positions (float[R*n][3], written).
// Push:     n_rays, n, near, far, seed, step, level, jitter, contraction, ray_offset (global index of ray 0, for the RNG).
// Threads:  one invocation per ray, 32 per group (one warp: a 4096-ray pass spreads over 128 SMs, not 64), folded
//           into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/sample_initial_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    float u = pc.jitter != 0u ? ray_uniform(pc.seed, pc.step, pc.ray_offset + r, pc.level) : 0.5;
    uint e0 = r * (pc.n + 1u);
    for (uint k = 0u; k <= pc.n; ++k) edges[e0 + k] = edge_s(k, u);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    WRITE_POSITIONS(edges, e0, pc.n, o, d, pc.near, pc.far, pc.contraction != 0u, pos, r * pc.n)
}
