// render_common.glsl: the nerfacto sampling geometry shared by the render kernels (spec/nerfacto.md §2.6-2.8, §2.10)
// and mirrored in src/reference/render.rs.
// - Spacing: UniformLinDispPiecewise g(t) = t/2 (t < 1), 1 - 1/(2t) (t >= 1); an edge s in [0,1] maps to
//   t = g^-1(s g(far) + (1 - s) g(near)), t along the unit ray direction.
// - Contraction (L-infinity): x if |x|_inf < 1, else (2 - 1/|x|_inf) x / |x|_inf; hash input p = (contract(x) + 2)/4.
//   Without contraction p = (x + 1)/2 for the box [-1,1]^3 and points outside it get no density.
// - Random numbers: PCG hash of (seed, step, ray, level) -> one uniform per ray and level (single jitter).

float spacing_g(float t) {
    return t < 1.0 ? 0.5 * t : 1.0 - 0.5 / t;
}

float spacing_g_inv(float s) {
    return s < 0.5 ? 2.0 * s : 1.0 / (2.0 - 2.0 * s);
}

// 1 - g(t) in closed form (no cancellation next to 1).
float spacing_one_minus_g(float t) {
    return t < 1.0 ? 1.0 - 0.5 * t : 0.5 / t;
}

// Euclidean distance of a normalised edge s. The linear-in-disparity branch is evaluated as
// 0.5 / (s (1 - g(far)) + (1 - s) (1 - g(near))): 1/(2 - 2a) cancels catastrophically next to a = 1 (5 % error in t at
// far = 1e6) and is 1/0 = Inf once g(far) rounds to 1 (far above ~1.7e7); this form is exact to rounding up to t = far.
float edge_to_t(float s, float near, float far) {
    float a = s * spacing_g(far) + (1.0 - s) * spacing_g(near);
    if (a < 0.5) return 2.0 * a;
    return 0.5 / (s * spacing_one_minus_g(far) + (1.0 - s) * spacing_one_minus_g(near));
}

vec3 contract_point(vec3 x) {
    float m = max(max(abs(x.x), abs(x.y)), abs(x.z));
    if (m < 1.0) return x; // branch-wise: no x / |x| at the origin (nerfacto.md §8.7)
    return (2.0 - 1.0 / m) * (x / m);
}

// Hash-grid input in [0,1]^3, and whether the point carries density (always with contraction).
vec3 hash_input(vec3 x, bool contraction, out bool inside) {
    if (contraction) {
        inside = true;
        return (contract_point(x) + 2.0) * 0.25;
    }
    vec3 p = (x + 1.0) * 0.5;
    inside = all(greaterThan(p, vec3(0.0))) && all(lessThan(p, vec3(1.0)));
    return inside ? p : vec3(0.0);
}

uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform in [0, 1) from (seed, step, ray, level).
float ray_uniform(uint seed, uint step, uint ray, uint level) {
    uint h = pcg_hash(seed ^ pcg_hash(step ^ pcg_hash(ray ^ pcg_hash(level))));
    return float(h >> 8u) * (1.0 / 16777216.0);
}

// Density activation: sigma = scale * exp(raw) in fp32 (trunc_exp forward). raw is capped at 88 (exp(88) = 1.65e38,
// the largest integer power below FLT_MAX): an overflowed sigma = +Inf times a zero-width interval (duplicate PDF
// edges) is NaN, which poisoned every later weight and the backward (docs/stability.md). Unchanged below 88; a NaN
// raw stays NaN (a comparison, not min(), whose NaN result is undefined) for the trainer's step guard to see.
float density_from_raw(float raw, float scale) {
    return scale * exp(raw > 88.0 ? 88.0 : raw);
}

// Density at a sample x on the ray: sigma from raw (density_from_raw), and without contraction 0 outside the
// [-1, 1]^3 box (only the box carries density there).
float density_at(float raw, float scale, vec3 x, bool contraction) {
    float s = density_from_raw(raw, scale);
    if (!contraction) {
        bool inside;
        hash_input(x, false, inside);
        if (!inside) s = 0.0;
    }
    return s;
}

// Opacity 1 - exp(-tau) of an interval. Below tau = 2^-7 a 4-term series (relative error < 2e-10): 1 - exp(-tau)
// cancels, and an exp that is one ulp off (lavapipe: exp(-4e-20) = 1 - 6e-8) turned near-empty space into weights
// of 6e-8 per sample, hence an accumulation of 1e-6 and a made-up expected depth (docs/stability.md).
float alpha_of(float tau) {
    return tau < 0.0078125 ? tau * (1.0 - tau * (0.5 - tau * (1.0 / 6.0 - tau * (1.0 / 24.0)))) : 1.0 - exp(-tau);
}

// Where inside an interval of optical thickness tau the accumulation reaches a fraction u in (0, 1] of the interval's
// weight: 1 - exp(-tau f) = u (1 - exp(-tau)), so f = -log((1 - u) + u exp(-tau)) / tau (written so that nothing
// cancels at large tau; below tau ~ 1e-3 fp32's log near 1 costs ~1e-3 of the interval, far below any footprint);
// f -> u as tau -> 0 (a thin interval fills linearly). Clamped to [0, 1].
float crossing_frac(float u, float tau) {
    u = clamp(u, 0.0, 1.0);
    if (tau < 1e-4) return u;
    return clamp(-log((1.0 - u) + u * exp(-tau)) / tau, 0.0, 1.0);
}

// d sigma / d raw with trunc_exp's clamped derivative: scale * exp(clamp(raw, -15, 15)).
float density_grad_scale(float raw, float scale) {
    return scale * exp(clamp(raw, -15.0, 15.0));
}

// Writes the hash inputs of the n intervals of a ray, from its n + 1 edges (s-space) in `edges[e0 ..]`.
#define WRITE_POSITIONS(EDGES, E0, N, ORIGIN, DIR, NEAR, FAR, CONTRACT, POS, P0)                        \
    {                                                                                                      \
        float t0_ = edge_to_t(EDGES[E0], NEAR, FAR);                                                     \
        for (uint i_ = 0u; i_ < (N); ++i_) {                                                             \
            float t1_ = edge_to_t(EDGES[(E0) + i_ + 1u], NEAR, FAR);                                      \
            bool in_;                                                                                    \
            vec3 p_ = hash_input((ORIGIN) + (DIR) * (0.5 * (t0_ + t1_)), CONTRACT, in_);                  \
            POS[3u * ((P0) + i_)] = p_.x;                                                                  \
            POS[3u * ((P0) + i_) + 1u] = p_.y;                                                             \
            POS[3u * ((P0) + i_) + 2u] = p_.z;                                                             \
            t0_ = t1_;                                                                                     \
        }                                                                                                  \
    }
