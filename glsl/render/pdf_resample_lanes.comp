// pdf_resample_lanes: pdf_resample (same bindings, push constants and formulas; results within fp32 rounding) with a
// ray's work spread over 32 lanes, for GPUs: the padded weights' total and the cdf are workgroup prefix sums over
// blocks of 32 bins (ray_lanes.glsl), the cdf is kept in shared memory, and each lane finds the bins of its new
// edges k = lane, lane + 32, ... by binary search (searchsorted right: the first cdf value greater than u), where
// the serial kernel merges. A lane also finds edge k + 1 to write the midpoint of interval k, so no lane reads
// another's output. For n <= PDF_LANES_MAX_BINS; the host runs pdf_resample above that.
// Bindings: 0 edges in (float[R][n+1]), 1 weights (float[R][n]), 2 edges out (float[R][m+1], written),
//           3 positions (float[R*m][3], written), 4 origins, 5 directions.
// Push:     n_rays, n, m, near, far, anneal, seed, step, level, jitter, contraction, ray_offset.
// Threads:  one workgroup of 32 per ray, folded into 2D past 65535 groups; 4 KiB of shared memory per workgroup.
#version 460
#define WG_SIZE 32
#define PDF_LANES_MAX_BINS 1024u
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_lanes.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/pdf_resample_io.glsl"

shared float cdf_s[PDF_LANES_MAX_BINS];

// New edge k (s-space) of ray r: the inverse of the piecewise-linear cdf at u_k.
float new_edge(uint r, uint k, float ju, float inv_m) {
    float u = (float(k) + ju) * inv_m;
    uint lo = 0u, hi = min(pc.n, PDF_LANES_MAX_BINS); // i = the number of cdf values <= u (bounded: see main)
    while (lo < hi) {
        uint mid = (lo + hi) >> 1u;
        if (cdf_s[mid] <= u) lo = mid + 1u; else hi = mid;
    }
    uint ei = r * (pc.n + 1u);
    if (lo >= pc.n) return edges_in[ei + pc.n]; // u beyond the last cdf value: clamped to the last edge
    float cdf_lo = lo == 0u ? 0.0 : cdf_s[lo - 1u];
    float den = cdf_s[lo] - cdf_lo;
    float tau = den > 0.0 ? clamp((u - cdf_lo) / den, 0.0, 1.0) : 0.0;
    return edges_in[ei + lo] + tau * (edges_in[ei + lo + 1u] - edges_in[ei + lo]);
}

void main() {
    uint r = group_index();
    if (r >= pc.n_rays) return; // uniform over the workgroup
    uint lane = lane_index();
    float total = 0.0;
    for (uint b = 0u; b < pc.n; b += LANES) {
        uint i = b + lane;
        total += lanes_add(i < pc.n ? padded_weight(r, i) : 0.0);
    }
    float pad = max(1e-5 - total, 0.0) / float(pc.n);
    total = max(total, 1e-5);
    float inv_total = 1.0 / total;
    float carry = 0.0;
    for (uint b = 0u; b < pc.n; b += LANES) {
        uint i = b + lane;
        float x = i < pc.n ? (padded_weight(r, i) + pad) * inv_total : 0.0;
        float block;
        float excl = lanes_exclusive_add(x, block);
        // Bounded by the array: past it the host runs pdf_resample, and a misrouted dispatch gives wrong edges
        // (which the tests see) rather than writes outside shared memory.
        if (i < pc.n && i < PDF_LANES_MAX_BINS) cdf_s[i] = min(1.0, carry + excl + x);
        carry += block;
    }
    barrier();
    float ju = pc.jitter != 0u ? ray_uniform(pc.seed, pc.step, pc.ray_offset + r, pc.level) : 0.5;
    float inv_m = 1.0 / float(pc.m + 1u);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    uint eo = r * (pc.m + 1u);
    for (uint k = lane; k <= pc.m; k += LANES) {
        float e0 = new_edge(r, k, ju, inv_m);
        edges_out[eo + k] = e0;
        if (k == pc.m) continue;
        float t0 = edge_to_t(e0, pc.near, pc.far);
        float t1 = edge_to_t(new_edge(r, k + 1u, ju, inv_m), pc.near, pc.far);
        bool inside;
        vec3 p = hash_input(o + d * (0.5 * (t0 + t1)), pc.contraction != 0u, inside);
        uint s = r * pc.m + k;
        pos[3u * s] = p.x;
        pos[3u * s + 1u] = p.y;
        pos[3u * s + 2u] = p.z;
    }
}
