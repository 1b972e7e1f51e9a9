// composite_io.glsl: what composite.comp and composite_lanes.comp share: their bindings and push constants (the
// layout in composite.comp's header), the per-band limit, and the per-sample helpers (depth loss term, density,
// background). Include after common/index.glsl and render/render_common.glsl.
layout(std430, binding = 0) readonly buffer Edges { float edges[]; };
layout(std430, binding = 1) readonly buffer Density { float density[]; };
layout(std430, binding = 2) readonly buffer Colours { float colours[]; };
layout(std430, binding = 3) readonly buffer Targets { float targets[]; };
layout(std430, binding = 4) readonly buffer BandWeights { float band_w[]; };
layout(std430, binding = 5) buffer DyDensity { float dy_density[]; };
layout(std430, binding = 6) writeonly buffer DyColour { float dy_colour[]; };
layout(std430, binding = 7) buffer Weights { float weights[]; };
layout(std430, binding = 8) writeonly buffer RayOut { float ray_out[]; };
layout(std430, binding = 9) readonly buffer Origins { float origins[]; };
layout(std430, binding = 10) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 11) readonly buffer DepthTargets { float depth_t[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n; uint bands; float near; float far; uint density_stride; float density_scale;
    uint background; float bg_value; float rgb_norm; float dist_norm; uint train; uint contraction; uint grad_scaling;
    uint seed; uint step; uint ray_offset; uint depth_mode; float depth_norm;
} pc;

const uint MAX_BANDS = 128u;
const float DS_EPS = 1e-7;
const float URF_SIGMA_SCALE = 3.0; // the Gaussian of the URF window has standard deviation s / 3
const float INV_SQRT_2PI = 0.3989422804014327;

// Depth loss of one sample (w, t, delta) against target (d, s), without the expected-depth term: its value and
// dL/dw (see the header).
vec2 depth_term(float w, float t, float delta, float d, float s) {
    float x = t - d;
    if (pc.depth_mode == 1u) {
        float k = INV_SQRT_2PI / s * exp(-x * x / (2.0 * s * s)) * delta;
        return vec2(-log(w + DS_EPS) * k, -k / (w + DS_EPS));
    }
    float sd = s / URF_SIGMA_SCALE;
    if (abs(x) <= s) {
        float nx = INV_SQRT_2PI / sd * exp(-0.5 * x * x / (sd * sd)) * delta;
        return vec2((w - nx) * (w - nx), 2.0 * (w - nx));
    }
    if (x < -s) return vec2(w * w, 2.0 * w);
    return vec2(0.0);
}

float sigma_of(uint r, uint i, vec3 o, vec3 d, float tmid) {
    float raw_i = density[(r * pc.n + i) * pc.density_stride];
    return density_at(raw_i, pc.density_scale, o + d * tmid, pc.contraction != 0u);
}

float bg_of(uint r, uint b) {
    if (pc.background == 2u) return ray_uniform(pc.seed, pc.step, pc.ray_offset + r, 100u + b);
    return pc.background == 0u ? colours[(r * pc.n + pc.n - 1u) * pc.bands + b] : pc.bg_value;
}
