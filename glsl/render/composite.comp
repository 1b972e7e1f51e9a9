// composite: NeRF-level volume rendering for B bands, the per-band MSE (eq. 3.1) and the distortion loss, and in
// training their backward in closed form (spec/nerfacto.md §2.10-2.12; twin: src/reference/render.rs).
// Forward per ray: sigma_i = scale exp(raw_i), w_i = T_i (1 - exp(-sigma_i delta_i)), A = sum w,
//   C = sum w_i c_i + bg (1 - A) with bg = c_{N-1} (last_sample), 0 (black), 1 (white) or a given constant.
// Loss (training): ray_weight * sum_b band_w_b (C_b - y_b)^2 * rgb_norm over the bands whose target y_b is not NaN
//   (NaN: the ray did not observe that band, rig-aware training); rgb_norm = 1 / (sum over rays of ray weight
//   times observed bands), i.e. 1/(rays * B) when every band is observed;
//   distortion in s-space, O(N): dist_norm * [2 sum w_i (m_i W_i - M_i) + 1/3 sum w_i^2 ds_i].
// Depth supervision (optional, depth_mode; spec in docs/geometry.md "Depth supervision"): per ray a target distance d
//   along the unit ray (normalised frame; d <= 0 or non-finite: no target) and a standard deviation s. With t_i the
//   interval midpoints and delta_i their lengths (URF's depth term (d - D)^2 is left out: nerfstudio's D is the
//   median, which passes no gradient; the expected depth would hand the far contracted samples, t up to `far`, the
//   largest gradients, and training collapsed when it did):
//   1 DS-NeRF: L = -sum_i log(w_i + 1e-7) N(t_i - d; 0, s) delta_i  (cross-entropy of the weights against the
//              target's Gaussian mass per interval);
//   2 URF:     L = sum_{|t_i - d| <= s} (w_i - N(t_i - d; 0, s/3) delta_i)^2 + sum_{t_i < d - s} w_i^2;
//   times depth_norm * ray_weight. N is the normal density, so N delta is a probability mass like w and both losses
//   do not grow as the scene's scale shrinks (nerfstudio's forms use N unnormalised (DS-NeRF) or unmultiplied by
//   delta (URF): with this project's aerial normalisation, 0.2 m is s ~ 0.002 and N peaks at ~600; docs/geometry.md). Functions of the weights only, so they enter
//   the backward as dL/dw_i.
// Backward: g_i = <G, c_i - bg> + dLd/dw_i + dLdepth/dw_i; dL/dsigma_k = delta_k (g_k T_{k+1} - sum_{i>k} g_i w_i);
//   dL/draw_k = dL/dsigma_k * scale exp(clamp(raw_k, -15, 15)); dL/dc_i = w_i G (+ (1 - A) G for the last sample with
//   last_sample background). The exclusive prefix of sigma delta is parked in dy_density during the forward pass.
// Outputs per ray (ray_out, stride RAY_OUT_FIXED + B; the named columns of render/ray_out.glsl): loss_rgb, loss_dist,
//   accumulation, median depth, expected depth, squared error (unweighted, summed over bands), depth quantiles q25
//   and q75 of the normalised weights, loss_depth, C_0..C_{B-1} (clamped to [0,1] in evaluation).
// Depths are exact crossings inside an interval, not its midpoint: inside [t0, t1) the density is constant, so the
//   accumulation there is A_prev + T_i (1 - exp(-sigma (t - t0))) and the level L is crossed at
//   t = t0 + delta * crossing_frac(u, tau), u = (L - A_prev) / w_i (see render_common.glsl). The median is the
//   crossing of A = 0.5 (nerfstudio's median level; the last midpoint when A never reaches it); q25 and q75 cross
//   0.25 A and 0.75 A, so q75 - q25 measures how spread the weights are along the ray (second pass over the weights).
// Bindings: 0 edges (float[R][N+1]), 1 density rows (raw at column 0 of density_stride), 2 colours (float[R*N][B]),
//           3 targets (float[R][B+1]: B values (NaN: not observed) then the ray weight), 4 band weights (float[B]),
//           5 dy_density (rows of density_stride: column 0 written), 6 dy_colour (float[R*N][B], written),
//           7 weights (float[R][N], written), 8 ray_out (float[R][9+B], written), 9 origins, 10 directions,
//           11 depth targets (float[R][2]: d, s; read only with depth_mode != 0, else any buffer).
// Push:     n_rays, n, bands, near, far, density_stride, density_scale, background (0 last_sample, 1 constant,
//           2 random: a uniform colour per ray and band from (seed, step, ray_offset + ray), as nerfstudio's `random`),
//           bg_value, rgb_norm, dist_norm, train, contraction, grad_scaling (1: nerfacto's optional gradient
//           scaling, every field-output gradient times clamp(t_mid^2, 0, 1), damping near-camera samples), seed, step,
//           ray_offset, depth_mode (0 off, 1 DS-NeRF, 2 URF), depth_norm.
// Threads:  one invocation per ray, serial over its samples (forward, then a reverse pass), 32 per group (one warp: a
//           4096-ray pass spreads over 128 SMs, not 64).
#version 460
#define WG_SIZE 32
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_out.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/composite_io.glsl"

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    uint e0 = r * (pc.n + 1u);
    uint B = pc.bands;
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);
    float C[MAX_BANDS];
    for (uint b = 0u; b < B; ++b) C[b] = 0.0;

    // Forward.
    float acc = 0.0, A = 0.0, W = 0.0, M = 0.0, dist = 0.0, depth_sum = 0.0;
    float median = -1.0;
    float t_first = edge_to_t(edges[e0], pc.near, pc.far);
    float t0 = t_first;
    float tmid_last = t0;
    for (uint i = 0u; i < pc.n; ++i) {
        float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
        float tmid = 0.5 * (t0 + t1);
        float tau = sigma_of(r, i, o, d, tmid) * (t1 - t0);
        float w = exp(-acc) * alpha_of(tau);
        w = isnan(w) ? 0.0 : w;
        if (pc.train != 0u) dy_density[(r * pc.n + i) * pc.density_stride] = acc; // exclusive prefix, reused below
        acc += tau;
        weights[r * pc.n + i] = w;
        for (uint b = 0u; b < B; ++b) C[b] += w * colours[(r * pc.n + i) * B + b];
        float s0 = edges[e0 + i], s1 = edges[e0 + i + 1u];
        float m = 0.5 * (s0 + s1);
        dist += 2.0 * w * (m * W - M) + w * w * (s1 - s0) / 3.0;
        W += w;
        M += w * m;
        if (median < 0.0 && A + w >= 0.5 && w > 0.0) median = t0 + (t1 - t0) * crossing_frac((0.5 - A) / w, tau);
        A += w;
        depth_sum += w * tmid;
        tmid_last = tmid;
        t0 = t1;
    }
    if (median < 0.0) median = tmid_last;
    // Second pass: the crossings of 0.25 A and 0.75 A (weights and intervals as stored above). Below A = 1e-4 the ray
    // holds no surface and the quantiles of its rounding-level weights mean nothing: both are the last midpoint.
    float q25 = -1.0, q75 = -1.0, Ap = 0.0;
    t0 = t_first;
    for (uint i = 0u; i < pc.n && q75 < 0.0 && A >= 1e-4; ++i) {
        float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
        float w = weights[r * pc.n + i];
        if (w > 0.0) {
            float tau = sigma_of(r, i, o, d, 0.5 * (t0 + t1)) * (t1 - t0);
            if (q25 < 0.0 && Ap + w >= 0.25 * A) q25 = t0 + (t1 - t0) * crossing_frac((0.25 * A - Ap) / w, tau);
            if (q75 < 0.0 && Ap + w >= 0.75 * A) q75 = t0 + (t1 - t0) * crossing_frac((0.75 * A - Ap) / w, tau);
        }
        Ap += w;
        t0 = t1;
    }
    if (q25 < 0.0) q25 = tmid_last;
    if (q75 < 0.0) q75 = tmid_last;
    float ray_w = targets[r * (B + 1u) + B];
    float expected = depth_sum / (A + 1e-10);
    // Depth target: present when depth supervision is on and the ray has a finite positive distance.
    float dt = 0.0, ds = 1.0;
    if (pc.depth_mode != 0u) {
        dt = depth_t[2u * r];
        ds = depth_t[2u * r + 1u];
    }
    bool has_depth = pc.depth_mode != 0u && dt > 0.0 && !isinf(dt) && ds > 0.0 && !isinf(ds);
    float loss_depth = 0.0;
    if (has_depth) {
        t0 = t_first;
        for (uint i = 0u; i < pc.n; ++i) {
            float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
            loss_depth += depth_term(weights[r * pc.n + i], 0.5 * (t0 + t1), t1 - t0, dt, ds).x;
            t0 = t1;
        }
    }
    float loss = 0.0, sq = 0.0;
    uint ro = r * (RAY_OUT_FIXED + B);
    for (uint b = 0u; b < B; ++b) {
        float c = C[b] + bg_of(r, b) * (1.0 - A);
        float y = targets[r * (B + 1u) + b];
        // A NaN target is a band this ray did not observe (rig-aware training): no loss, no gradient. (An infinite
        // one is a corrupt value: it makes the loss infinite and the NaN/Inf guard skips the step.)
        float e = isnan(y) ? 0.0 : c - y;
        loss += band_w[b] * e * e;
        sq += e * e;
        ray_out[ro + RAY_OUT_FIXED + b] = pc.train != 0u ? c : clamp(isnan(c) ? 0.0 : c, 0.0, 1.0);
        C[b] = 2.0 * band_w[b] * e * pc.rgb_norm * ray_w; // from here on C holds G = dL/dC
    }
    ray_out[ro + RO_LOSS_RGB] = loss * pc.rgb_norm * ray_w;
    ray_out[ro + RO_LOSS_DISTORTION] = dist * pc.dist_norm * ray_w;
    ray_out[ro + RO_ACCUMULATION] = A;
    ray_out[ro + RO_MEDIAN_DEPTH] = median;
    ray_out[ro + RO_EXPECTED_DEPTH] = expected;
    ray_out[ro + RO_SQUARED_ERROR] = sq * ray_w;
    ray_out[ro + RO_DEPTH_Q25] = q25;
    ray_out[ro + RO_DEPTH_Q75] = q75;
    ray_out[ro + RO_LOSS_DEPTH] = loss_depth * pc.depth_norm * ray_w;
    if (pc.train == 0u) return;

    // Backward: reverse pass with suffix sums S = sum_{i>k} g_i w_i, Sw = sum_{i>k} w_i, Swm = sum_{i>k} w_i m_i.
    float S = 0.0, Sw = 0.0, Swm = 0.0;
    float Gbg = 0.0;
    for (uint b = 0u; b < B; ++b) Gbg += C[b] * bg_of(r, b);
    float t1 = edge_to_t(edges[e0 + pc.n], pc.near, pc.far);
    for (uint kk = 0u; kk < pc.n; ++kk) {
        uint k = pc.n - 1u - kk;
        float t0k = edge_to_t(edges[e0 + k], pc.near, pc.far);
        float delta = t1 - t0k;
        uint di = (r * pc.n + k) * pc.density_stride;
        float raw = density[di];
        float sigma = sigma_of(r, k, o, d, 0.5 * (t0k + t1));
        float t_next = exp(-(dy_density[di] + sigma * delta)); // T_{k+1}
        float w = weights[r * pc.n + k];
        float tmid = 0.5 * (t0k + t1);
        float gs = pc.grad_scaling != 0u ? min(tmid * tmid, 1.0) : 1.0;
        float g = -Gbg;
        for (uint b = 0u; b < B; ++b) {
            float gb = C[b];
            g += gb * colours[(r * pc.n + k) * B + b];
            float dc = w * gb;
            if (k == pc.n - 1u && pc.background == 0u) dc += (1.0 - A) * gb;
            dy_colour[(r * pc.n + k) * B + b] = dc * gs;
        }
        // Distortion gradient (edges detached): W_k = W - w - Sw, M_k = M - w m - Swm.
        float s0 = edges[e0 + k], s1 = edges[e0 + k + 1u];
        float m = 0.5 * (s0 + s1);
        float Wk = W - w - Sw, Mk = M - w * m - Swm;
        float gd = 2.0 * (m * Wk - Mk + (M - Mk - w * m) - m * (W - Wk - w)) + (2.0 / 3.0) * w * (s1 - s0);
        g += gd * pc.dist_norm * ray_w;
        if (has_depth) {
            float gdep = depth_term(w, tmid, delta, dt, ds).y;
            g += gdep * pc.depth_norm * ray_w;
        }
        float dsigma = delta * (g * t_next - S);
        bool live = pc.contraction != 0u || sigma > 0.0;
        dy_density[di] = live ? dsigma * density_grad_scale(raw, pc.density_scale) * gs : 0.0;
        S += g * w;
        Sw += w;
        Swm += w * m;
        t1 = t0k;
    }
}
