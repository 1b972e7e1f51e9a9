// interlevel_lanes: interlevel (same bindings, push constants, loss and gradient; results within fp32 rounding) with
// a ray's work spread over 32 lanes, for GPUs. Formulas: interlevel.comp. Where the serial kernel walks two pointers
// and a difference array, this one uses sorted-array searches and prefix sums (lo and h only grow with i):
// - P = exclusive prefix of the proposal weights (shared); NeRF interval i (one per lane and block) finds lo_i (the
//   last proposal interval whose start <= c_i) and hi_i (the number of proposal ends <= c_{i+1}) by binary search;
//   w_outer_i = P[h_i + 1] - P[lo_i], h_i = min(hi_i, n - 1), as the serial kernel's running sums;
// - g_j = sum of gcoef_i over the i with lo_i <= j <= h_i, i.e. over a_j <= i <= b_j with a_j the first i with
//   h_i >= j and b_j the last i with lo_i <= j (both searches, as lo and h are sorted); summed term by term, not as a
//   difference of prefix sums, so a sample no interval reaches gets exactly 0 (nerfstudio's oracle checks that);
// - forward over blocks of proposal samples: the exclusive prefix of sigma delta (stored in prop weights) and g
//   (stored in dy); then backward over blocks from the far end with lanes in reverse order, so the suffix sum
//   S_k = sum_{j>k} g_j w_j is a prefix sum: dL/dsigma_k = delta_k (g_k T_{k+1} - S_k).
// For n_nerf <= 256 and n_prop <= 1024 (about 7 KiB of shared memory); the host runs interlevel above that.
// Bindings: 0 nerf edges (float[R][N+1]), 1 nerf weights (float[R][N]), 2 proposal edges (float[R][n+1]),
//           3 proposal raw (rows of raw_stride), 4 proposal weights (float[R][n]; read, then overwritten),
//           5 proposal dy (rows of raw_stride: column 0 written), 6 losses (float[R], written), 7 origins, 8 directions.
// Push:     n_rays, n_nerf, n_prop, near, far, raw_stride, density_scale, norm, contraction.
// Threads:  one workgroup of 32 per ray, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 32
#define IL_LANES_MAX_NERF 256u
#define IL_LANES_MAX_PROP 1024u
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_lanes.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/interlevel_io.glsl"

shared float p_s[IL_LANES_MAX_PROP + 1u]; // exclusive prefix of the proposal weights
shared float gc_s[IL_LANES_MAX_NERF]; // gcoef per NeRF interval
shared uint lo_s[IL_LANES_MAX_NERF];
shared uint h_s[IL_LANES_MAX_NERF];

// Number of j in [j0, j1) with cp[pe + j + off] <= x (the proposal edges are sorted).
uint count_le(uint pe, uint j0, uint j1, uint off, float x) {
    uint lo = j0, hi = j1;
    while (lo < hi) {
        uint mid = (lo + hi) >> 1u;
        if (cp[pe + mid + off] <= x) lo = mid + 1u; else hi = mid;
    }
    return lo - j0;
}

void main() {
    uint r = group_index();
    if (r >= pc.n_rays) return; // uniform over the workgroup
    uint lane = lane_index();
    uint N = pc.n_nerf, n = pc.n_prop;
    uint ce = r * (N + 1u), pe = r * (n + 1u), wo = r * n;
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);

    // P: exclusive prefix of the proposal weights.
    float carry = 0.0;
    for (uint b = 0u; b < n; b += LANES) {
        uint j = b + lane;
        float x = j < n ? wp[wo + j] : 0.0;
        float block;
        float excl = lanes_exclusive_add(x, block);
        if (j < n) p_s[j] = carry + excl;
        carry += block;
    }
    if (lane == 0u) p_s[n] = carry;
    barrier();

    // Loss per NeRF interval, and its gradient coefficient.
    float loss = 0.0;
    for (uint i = lane; i < N; i += LANES) {
        uint lo = count_le(pe, 1u, n, 0u, c[ce + i]);      // last start <= c_i, clamped to [0, n - 1]
        uint hi = count_le(pe, 0u, n, 1u, c[ce + i + 1u]); // proposal ends <= c_{i+1}
        uint h = min(hi, n - 1u);
        float outer = h >= lo ? p_s[h + 1u] - p_s[lo] : 0.0;
        float wi = w[r * N + i];
        float excess = max(wi - outer, 0.0);
        loss += excess * excess / (wi + 1e-7);
        gc_s[i] = excess > 0.0 && h >= lo ? -2.0 * excess / (wi + 1e-7) * pc.norm : 0.0;
        lo_s[i] = lo;
        h_s[i] = h;
    }
    loss = lanes_add(loss);
    if (lane == 0u) losses[r] = loss * pc.norm;
    barrier();

    // Forward over the proposal samples: g_j into dy, the exclusive prefix of tau into wp.
    float acc = 0.0;
    for (uint b = 0u; b < n; b += LANES) {
        uint j = b + lane;
        float tau = 0.0;
        if (j < n) {
            // a_j = first i with h_i >= j, b_j = last i with lo_i <= j.
            uint lo = 0u, hi = N;
            while (lo < hi) {
                uint mid = (lo + hi) >> 1u;
                if (h_s[mid] < j) lo = mid + 1u; else hi = mid;
            }
            uint a = lo;
            lo = 0u;
            hi = N;
            while (lo < hi) {
                uint mid = (lo + hi) >> 1u;
                if (lo_s[mid] <= j) lo = mid + 1u; else hi = mid;
            }
            float g = 0.0;
            for (uint i = a; i < lo; ++i) g += gc_s[i];
            dy[(wo + j) * pc.raw_stride] = g;
            float t0 = edge_to_t(cp[pe + j], pc.near, pc.far);
            float t1 = edge_to_t(cp[pe + j + 1u], pc.near, pc.far);
            tau = prop_sigma(r, j, o, d, 0.5 * (t0 + t1)) * (t1 - t0);
        }
        float block;
        float excl = lanes_exclusive_add(tau, block);
        if (j < n) wp[wo + j] = acc + excl;
        acc += block;
    }
    memoryBarrierBuffer();
    barrier();

    // Backward from the far end, lanes in reverse order: S_k = sum_{j>k} g_j w_j is an exclusive prefix sum.
    float S = 0.0;
    uint n_blocks = (n + LANES - 1u) / LANES;
    for (uint bb = 0u; bb < n_blocks; ++bb) {
        uint b = (n_blocks - 1u - bb) * LANES;
        uint k = b + (LANES - 1u - lane);
        float gw = 0.0, g = 0.0, dsig = 0.0, excl = 0.0, tau = 0.0, delta = 0.0, sigma = 0.0;
        uint di = (wo + k) * pc.raw_stride;
        if (k < n) {
            float t0 = edge_to_t(cp[pe + k], pc.near, pc.far);
            float t1 = edge_to_t(cp[pe + k + 1u], pc.near, pc.far);
            delta = t1 - t0;
            sigma = prop_sigma(r, k, o, d, 0.5 * (t0 + t1));
            tau = sigma * delta;
            excl = wp[wo + k];
            float wk = exp(-excl) * alpha_of(tau);
            wk = isnan(wk) ? 0.0 : wk;
            g = dy[di];
            gw = g * wk;
        }
        float block;
        float after = S + lanes_exclusive_add(gw, block);
        if (k < n) {
            float dsigma = delta * (g * exp(-(excl + tau)) - after);
            bool live = pc.contraction != 0u || sigma > 0.0;
            dy[di] = live ? dsigma * density_grad_scale(raw[di], pc.density_scale) : 0.0;
        }
        S += block;
    }
}
