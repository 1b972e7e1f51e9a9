// sample_initial_edges: sample_initial (same bindings, push constants and results, bit for bit) with one invocation
// per edge instead of one per ray, for GPUs (RenderKernels picks it with the other per-ray `_lanes` kernels). The
// piecewise initial sampler (spec/nerfacto.md §2.6). Per ray n + 1 edges in normalised spacing
// s_k = k/n, jittered in training with one uniform per ray (single jitter: edge_k = lower_k + u (upper_k - lower_k),
// lower/upper the midpoints to the neighbouring edges), unjittered in evaluation; then the hash-grid inputs of the n
// interval midpoints (contracted).
// Bindings: 0 origins (float[3R]), 1 directions (float[3R]), 2 edges (float[R][n+1], written),
//           3 positions (float[R*n][3], written).
// Push:     n_rays, n, near, far, seed, step, level, jitter, contraction, ray_offset (global index of ray 0, for the RNG).
// Threads:  one invocation per edge (ray r = index / (n + 1), edge k = index % (n + 1)): it writes edge k and, for
//           k < n, the midpoint of interval k, computing edge k + 1 itself (the same formula, so bit for bit what a
//           loop over the ray gives). A 4096-ray pass is 4096 (n + 1) invocations, not 4096 serial loops (on lavapipe
//           the serial kernel is faster: it hashes the ray's uniform once).
//           64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "render/render_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/sample_initial_io.glsl"

void main() {
    uint idx = global_index();
    uint r = idx / (pc.n + 1u);
    uint k = idx - r * (pc.n + 1u);
    if (r >= pc.n_rays) return;
    float u = pc.jitter != 0u ? ray_uniform(pc.seed, pc.step, pc.ray_offset + r, pc.level) : 0.5;
    float e0 = edge_s(k, u);
    edges[r * (pc.n + 1u) + k] = e0;
    if (k == pc.n) return;
    float t0 = edge_to_t(e0, pc.near, pc.far);
    float t1 = edge_to_t(edge_s(k + 1u, u), pc.near, pc.far);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    bool inside;
    vec3 p = hash_input(o + d * (0.5 * (t0 + t1)), pc.contraction != 0u, inside);
    uint s = r * pc.n + k;
    pos[3u * s] = p.x;
    pos[3u * s + 1u] = p.y;
    pos[3u * s + 2u] = p.z;
}
