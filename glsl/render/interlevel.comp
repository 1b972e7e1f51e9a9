// interlevel: the proposal (interlevel) loss of one proposal level and its backward to that level's raw densities
// (spec/nerfacto.md §2.12; twin: src/reference/render.rs). NeRF edges c and weights w are detached. For NeRF interval
// i: lo = last proposal interval whose start <= c_i, hi = first proposal interval whose end > c_{i+1} (both clamped to
// [0, n-1]), w_outer_i = sum_{j=lo..hi} wp_j; loss = norm * sum_i max(0, w_i - w_outer_i)^2 / (w_i + 1e-7), with
// norm = mult / (rays * N). dL/dwp_j collects -2 norm max(0, .)/(w_i + 1e-7) over every i whose [lo, hi] covers j
// (difference array + prefix sum), then reaches the raw densities through the weights' backward (as in composite).
// lo and hi only grow with i, so w_outer comes from running prefix sums: O(N + n) per ray.
// Scratch use: dy holds the difference array, then g; prop_weights is overwritten with the exclusive prefix of
// sigma delta (the weights are not needed after this kernel).
// Bindings: 0 nerf edges (float[R][N+1]), 1 nerf weights (float[R][N]), 2 proposal edges (float[R][n+1]),
//           3 proposal raw (rows of raw_stride), 4 proposal weights (float[R][n]; read, then overwritten),
//           5 proposal dy (rows of raw_stride: column 0 written), 6 losses (float[R], written), 7 origins, 8 directions.
// Push:     n_rays, n_nerf, n_prop, near, far, raw_stride, density_scale, norm, contraction.
// Threads:  one invocation per ray, 32 per group (one warp: a 4096-ray pass spreads over 128 SMs, not 64), folded
//           into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/interlevel_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    uint N = pc.n_nerf, n = pc.n_prop;
    uint ce = r * (N + 1u), pe = r * (n + 1u), wo = r * n;
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    for (uint j = 0u; j < n; ++j) dy[(wo + j) * pc.raw_stride] = 0.0;

    // Loss with running prefix sums: p_lo = sum_{j < lo} wp_j, p_hi = sum_{j < hi_count} wp_j.
    float loss = 0.0;
    uint lo = 0u, hi_count = 0u; // hi_count = number of proposal ends <= c_{i+1}
    float p_lo = 0.0, p_hi = 0.0;
    for (uint i = 0u; i < N; ++i) {
        float c0 = c[ce + i], c1 = c[ce + i + 1u];
        while (lo + 1u < n && cp[pe + lo + 1u] <= c0) {
            p_lo += wp[wo + lo];
            lo += 1u;
        }
        while (hi_count < n && cp[pe + hi_count + 1u] <= c1) {
            p_hi += wp[wo + hi_count];
            hi_count += 1u;
        }
        uint h = min(hi_count, n - 1u);
        float outer = h >= lo ? p_hi + (hi_count < n ? wp[wo + hi_count] : 0.0) - p_lo : 0.0;
        float wi = w[r * N + i];
        float excess = max(wi - outer, 0.0);
        loss += excess * excess / (wi + 1e-7);
        if (excess > 0.0 && h >= lo) {
            float gcoef = -2.0 * excess / (wi + 1e-7) * pc.norm;
            dy[(wo + lo) * pc.raw_stride] += gcoef;
            if (h + 1u < n) dy[(wo + h + 1u) * pc.raw_stride] -= gcoef;
        }
    }
    losses[r] = loss * pc.norm;

    // g_j = prefix sum of the difference array; the exclusive prefix of tau goes into wp (forward pass).
    float run = 0.0, acc = 0.0;
    float t0 = edge_to_t(cp[pe], pc.near, pc.far);
    for (uint j = 0u; j < n; ++j) {
        run += dy[(wo + j) * pc.raw_stride];
        dy[(wo + j) * pc.raw_stride] = run;
        float t1 = edge_to_t(cp[pe + j + 1u], pc.near, pc.far);
        wp[wo + j] = acc;
        acc += prop_sigma(r, j, o, d, 0.5 * (t0 + t1)) * (t1 - t0);
        t0 = t1;
    }
    // Reverse pass: dL/dsigma_k = delta_k (g_k T_{k+1} - sum_{j>k} g_j w_j).
    float S = 0.0;
    float t1 = edge_to_t(cp[pe + n], pc.near, pc.far);
    for (uint jj = 0u; jj < n; ++jj) {
        uint k = n - 1u - jj;
        float t0k = edge_to_t(cp[pe + k], pc.near, pc.far);
        float delta = t1 - t0k;
        uint di = (wo + k) * pc.raw_stride;
        float sigma = prop_sigma(r, k, o, d, 0.5 * (t0k + t1));
        float tau = sigma * delta;
        float excl = wp[wo + k];
        float wk = exp(-excl) * alpha_of(tau);
        wk = isnan(wk) ? 0.0 : wk;
        float g = dy[di];
        float dsigma = delta * (g * exp(-(excl + tau)) - S);
        bool live = pc.contraction != 0u || sigma > 0.0;
        dy[di] = live ? dsigma * density_grad_scale(raw[di], pc.density_scale) : 0.0;
        S += g * wk;
        t1 = t0k;
    }
}
