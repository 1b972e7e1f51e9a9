// pdf_resample: proposal resampling (spec/nerfacto.md §2.7). From a level's n + 1 edges and n weights:
// w'_i = w_i^anneal + 0.01 (0^0 = 1), sum floored at 1e-5; cdf; m + 1 new edges at u_k = (k + jitter)/(m+1) in training
// (one uniform per ray) or (k + 0.5)/(m+1) in evaluation, inverted piecewise-linearly (searchsorted right, clamped, 0/0
// -> 0); then the hash-grid inputs of the m new midpoints. Edges are detached: no gradient flows through resampling.
// Bindings: 0 edges in (float[R][n+1]), 1 weights (float[R][n]), 2 edges out (float[R][m+1], written),
//           3 positions (float[R*m][3], written), 4 origins, 5 directions.
// Push:     n_rays, n, m, near, far, anneal, seed, step, level, jitter, contraction, ray_offset.
// Threads:  one invocation per ray (two-pointer merge over the sorted u and cdf), 32 per group (one warp: a 4096-ray
//           pass spreads over 128 SMs, not 64), folded into 2D.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/pdf_resample_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    uint ei = r * (pc.n + 1u);
    uint eo = r * (pc.m + 1u);
    float total = 0.0;
    for (uint i = 0u; i < pc.n; ++i) total += padded_weight(r, i);
    float pad = max(1e-5 - total, 0.0) / float(pc.n);
    total = max(total, 1e-5);
    float inv_total = 1.0 / total;
    float ju = pc.jitter != 0u ? ray_uniform(pc.seed, pc.step, pc.ray_offset + r, pc.level) : 0.5;
    float inv_m = 1.0 / float(pc.m + 1u);
    // Walk the cdf: [cdf_lo, cdf_hi] is the bin of edges (i, i + 1); idx = first cdf index greater than u.
    uint i = 0u;
    float cdf_lo = 0.0;
    float cdf_hi = min(1.0, (padded_weight(r, 0u) + pad) * inv_total);
    for (uint k = 0u; k <= pc.m; ++k) {
        float u = (float(k) + ju) * inv_m;
        while (i < pc.n && cdf_hi <= u) {
            i += 1u;
            cdf_lo = cdf_hi;
            cdf_hi = i < pc.n ? min(1.0, cdf_hi + (padded_weight(r, i) + pad) * inv_total) : cdf_hi;
        }
        float e;
        if (i >= pc.n) {
            e = edges_in[ei + pc.n]; // u beyond the last cdf value: clamped to the last edge
        } else {
            float den = cdf_hi - cdf_lo;
            float tau = den > 0.0 ? clamp((u - cdf_lo) / den, 0.0, 1.0) : 0.0;
            e = edges_in[ei + i] + tau * (edges_in[ei + i + 1u] - edges_in[ei + i]);
        }
        edges_out[eo + k] = e;
    }
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    WRITE_POSITIONS(edges_out, eo, pc.m, o, d, pc.near, pc.far, pc.contraction != 0u, pos, r * pc.m)
}
