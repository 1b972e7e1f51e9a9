// composite_lanes: composite (same bindings, push constants, formulas and outputs; results within fp32 rounding) with
// a ray's samples spread over 32 lanes, for GPUs. Formulas, outputs and the backward: composite.comp; twin:
// src/reference/render.rs. What the serial kernel accumulates along the ray becomes prefix sums over blocks of 32
// samples (ray_lanes.glsl), kept in shared memory for the later passes:
// - forward: the exclusive prefixes of sigma delta (transmittance), w and w m (distortion) per sample; the colour,
//   per band, by the lanes over bands (each sums its band over the samples in order, as the serial kernel);
// - the median, q25 and q75 are the first samples whose inclusive weight prefix reaches the level (a minimum over
//   the lanes), then the same exact crossing inside that interval;
// - backward: blocks from the far end, lanes in reverse order, so the suffix sums S, Sw and Swm are prefix sums; the
//   distortion gradient takes W_k and M_k from the forward prefixes instead of W - w - Sw.
// The exclusive prefix of sigma delta stays in shared memory: dy_density is written once, with the gradient.
// For n <= COMPOSITE_LANES_MAX_SAMPLES (256), where the host runs composite above that; B <= 128 for both kernels
// (the host refuses more: `COMPOSITE_MAX_BANDS`).
// Bindings: as composite.comp (0 edges, 1 density rows, 2 colours, 3 targets, 4 band weights, 5 dy_density, 6
//           dy_colour, 7 weights, 8 ray_out, 9 origins, 10 directions, 11 depth targets).
// Push:     as composite.comp.
// Threads:  one workgroup of 32 per ray, folded into 2D past 65535 groups; about 4.8 KiB of shared memory.
#version 460
#define WG_SIZE 32
#define COMPOSITE_LANES_MAX_SAMPLES 256u
#include "common/index.glsl"
#include "render/render_common.glsl"
#include "render/ray_out.glsl"
#include "render/ray_lanes.glsl"
layout(local_size_x = WG_SIZE) in;
#include "render/composite_io.glsl"

shared float w_s[COMPOSITE_LANES_MAX_SAMPLES];   // weights
shared float wex_s[COMPOSITE_LANES_MAX_SAMPLES]; // exclusive prefix of w
shared float mex_s[COMPOSITE_LANES_MAX_SAMPLES]; // exclusive prefix of w m (m: the interval's s-space midpoint)
shared float tex_s[COMPOSITE_LANES_MAX_SAMPLES]; // exclusive prefix of sigma delta
shared float g_s[MAX_BANDS];                     // dL/dC per band

// Where the accumulation crosses `level` inside interval i (the first whose inclusive weight prefix reaches it), or
// the last midpoint when no interval does (i >= n).
float crossing_at(uint r, uint i, float level, vec3 o, vec3 d, float tmid_last) {
    if (i >= pc.n) return tmid_last;
    uint e0 = r * (pc.n + 1u);
    float t0 = edge_to_t(edges[e0 + i], pc.near, pc.far);
    float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
    float tau = sigma_of(r, i, o, d, 0.5 * (t0 + t1)) * (t1 - t0);
    return t0 + (t1 - t0) * crossing_frac((level - wex_s[i]) / w_s[i], tau);
}

void main() {
    uint r = group_index();
    if (r >= pc.n_rays) return; // uniform over the workgroup
    uint lane = lane_index();
    uint n = pc.n, B = pc.bands;
    uint e0 = r * (n + 1u);
    vec3 o = vec3(origins[3u * r], origins[3u * r + 1u], origins[3u * r + 2u]);
    vec3 d = vec3(dirs[3u * r], dirs[3u * r + 1u], dirs[3u * r + 2u]);

    // Forward over blocks of 32 samples.
    float acc = 0.0, Wc = 0.0, Mc = 0.0; // carries: sigma delta, w, w m over the blocks before
    float dist = 0.0, depth_sum = 0.0;   // this lane's shares
    uint med_i = n;
    for (uint b0 = 0u; b0 < n; b0 += LANES) {
        uint i = b0 + lane;
        bool ok = i < n;
        float t0 = 0.0, t1 = 0.0, tau = 0.0, s0 = 0.0, s1 = 0.0;
        if (ok) {
            s0 = edges[e0 + i];
            s1 = edges[e0 + i + 1u];
            t0 = edge_to_t(s0, pc.near, pc.far);
            t1 = edge_to_t(s1, pc.near, pc.far);
            tau = sigma_of(r, i, o, d, 0.5 * (t0 + t1)) * (t1 - t0);
        }
        float blk;
        float ex = acc + lanes_exclusive_add(tau, blk);
        acc += blk;
        float w = 0.0;
        if (ok) {
            w = exp(-ex) * alpha_of(tau);
            w = isnan(w) ? 0.0 : w;
        }
        float m = 0.5 * (s0 + s1);
        float Wi = Wc + lanes_exclusive_add(w, blk);
        Wc += blk;
        float Mi = Mc + lanes_exclusive_add(w * m, blk);
        Mc += blk;
        if (ok) {
            w_s[i] = w;
            wex_s[i] = Wi;
            mex_s[i] = Mi;
            tex_s[i] = ex;
            weights[r * n + i] = w;
            dist += 2.0 * w * (m * Wi - Mi) + w * w * (s1 - s0) / 3.0;
            depth_sum += w * 0.5 * (t0 + t1);
            if (Wi + w >= 0.5 && w > 0.0) med_i = min(med_i, i);
        }
    }
    float A = Wc;
    dist = lanes_add(dist);
    depth_sum = lanes_add(depth_sum);
    med_i = lanes_min_u(med_i);
    barrier(); // the shared per-sample arrays are complete
    float t_penult = edge_to_t(edges[e0 + n - 1u], pc.near, pc.far);
    float tmid_last = 0.5 * (t_penult + edge_to_t(edges[e0 + n], pc.near, pc.far));
    float median = crossing_at(r, med_i, 0.5, o, d, tmid_last);
    // The crossings of 0.25 A and 0.75 A; below A = 1e-4 both are the last midpoint (composite.comp).
    uint q25_i = n, q75_i = n;
    if (A >= 1e-4) {
        for (uint i = lane; i < n; i += LANES) {
            float w = w_s[i], Wi = wex_s[i];
            if (w > 0.0 && Wi + w >= 0.25 * A) q25_i = min(q25_i, i);
            if (w > 0.0 && Wi + w >= 0.75 * A) q75_i = min(q75_i, i);
        }
    }
    q25_i = lanes_min_u(q25_i);
    q75_i = lanes_min_u(q75_i);
    float q25 = crossing_at(r, q25_i, 0.25 * A, o, d, tmid_last);
    float q75 = crossing_at(r, q75_i, 0.75 * A, o, d, tmid_last);
    float ray_w = targets[r * (B + 1u) + B];
    float expected = depth_sum / (A + 1e-10);
    float dt = 0.0, ds = 1.0;
    if (pc.depth_mode != 0u) {
        dt = depth_t[2u * r];
        ds = depth_t[2u * r + 1u];
    }
    bool has_depth = pc.depth_mode != 0u && dt > 0.0 && !isinf(dt) && ds > 0.0 && !isinf(ds);
    float loss_depth = 0.0;
    if (has_depth) {
        for (uint i = lane; i < n; i += LANES) {
            float t0 = edge_to_t(edges[e0 + i], pc.near, pc.far);
            float t1 = edge_to_t(edges[e0 + i + 1u], pc.near, pc.far);
            loss_depth += depth_term(w_s[i], 0.5 * (t0 + t1), t1 - t0, dt, ds).x;
        }
    }
    loss_depth = lanes_add(loss_depth);

    // Colours, losses and dL/dC: the lanes over the bands.
    uint ro = r * (RAY_OUT_FIXED + B);
    float loss = 0.0, sq = 0.0, gbg = 0.0;
    for (uint b = lane; b < B; b += LANES) {
        float cb = 0.0;
        for (uint i = 0u; i < n; ++i) cb += w_s[i] * colours[(r * n + i) * B + b];
        float bg = bg_of(r, b);
        float c = cb + bg * (1.0 - A);
        float y = targets[r * (B + 1u) + b];
        float e = isnan(y) ? 0.0 : c - y; // NaN target: a band this ray did not observe (composite.comp)
        loss += band_w[b] * e * e;
        sq += e * e;
        ray_out[ro + RAY_OUT_FIXED + b] = pc.train != 0u ? c : clamp(isnan(c) ? 0.0 : c, 0.0, 1.0);
        float g = 2.0 * band_w[b] * e * pc.rgb_norm * ray_w;
        g_s[b] = g;
        gbg += g * bg;
    }
    loss = lanes_add(loss);
    sq = lanes_add(sq);
    float Gbg = lanes_add(gbg);
    if (lane == 0u) {
        ray_out[ro + RO_LOSS_RGB] = loss * pc.rgb_norm * ray_w;
        ray_out[ro + RO_LOSS_DISTORTION] = dist * pc.dist_norm * ray_w;
        ray_out[ro + RO_ACCUMULATION] = A;
        ray_out[ro + RO_MEDIAN_DEPTH] = median;
        ray_out[ro + RO_EXPECTED_DEPTH] = expected;
        ray_out[ro + RO_SQUARED_ERROR] = sq * ray_w;
        ray_out[ro + RO_DEPTH_Q25] = q25;
        ray_out[ro + RO_DEPTH_Q75] = q75;
        ray_out[ro + RO_LOSS_DEPTH] = loss_depth * pc.depth_norm * ray_w;
    }
    if (pc.train == 0u) return; // uniform
    barrier(); // g_s is complete

    // Backward from the far end, lanes in reverse order: S, Sw and Swm (sums over i > k) are exclusive prefix sums.
    float S = 0.0, Sw = 0.0, Swm = 0.0;
    uint n_blocks = (n + LANES - 1u) / LANES;
    for (uint bb = 0u; bb < n_blocks; ++bb) {
        uint k = (n_blocks - 1u - bb) * LANES + (LANES - 1u - lane);
        bool ok = k < n;
        float w = 0.0, m = 0.0, s0 = 0.0, s1 = 0.0;
        if (ok) {
            w = w_s[k];
            s0 = edges[e0 + k];
            s1 = edges[e0 + k + 1u];
            m = 0.5 * (s0 + s1);
        }
        float blk;
        float sw_k = Sw + lanes_exclusive_add(w, blk);
        Sw += blk;
        float swm_k = Swm + lanes_exclusive_add(w * m, blk);
        Swm += blk;
        float g = 0.0, delta = 0.0, sigma = 0.0, tau = 0.0, gs = 1.0;
        if (ok) {
            float t0k = edge_to_t(s0, pc.near, pc.far);
            float t1 = edge_to_t(s1, pc.near, pc.far);
            delta = t1 - t0k;
            float tmid = 0.5 * (t0k + t1);
            sigma = sigma_of(r, k, o, d, tmid);
            tau = sigma * delta;
            gs = pc.grad_scaling != 0u ? min(tmid * tmid, 1.0) : 1.0;
            g = -Gbg;
            for (uint b = 0u; b < B; ++b) {
                float gb = g_s[b];
                g += gb * colours[(r * n + k) * B + b];
                float dc = w * gb;
                if (k == n - 1u && pc.background == 0u) dc += (1.0 - A) * gb;
                dy_colour[(r * n + k) * B + b] = dc * gs;
            }
            // Distortion gradient (edges detached), with W_k, M_k the forward prefixes.
            float Wk = wex_s[k], Mk = mex_s[k];
            float gd = 2.0 * (m * Wk - Mk + swm_k - m * sw_k) + (2.0 / 3.0) * w * (s1 - s0);
            g += gd * pc.dist_norm * ray_w;
            if (has_depth) g += depth_term(w, tmid, delta, dt, ds).y * pc.depth_norm * ray_w;
        }
        float s_k = S + lanes_exclusive_add(g * w, blk);
        S += blk;
        if (ok) {
            uint di = (r * n + k) * pc.density_stride;
            float t_next = exp(-(tex_s[k] + tau)); // T_{k+1}
            float dsigma = delta * (g * t_next - s_k);
            bool live = pc.contraction != 0u || sigma > 0.0;
            dy_density[di] = live ? dsigma * density_grad_scale(density[di], pc.density_scale) * gs : 0.0;
        }
    }
}
