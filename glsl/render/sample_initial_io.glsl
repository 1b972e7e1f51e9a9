// sample_initial_io.glsl: what sample_initial.comp and sample_initial_edges.comp share: their bindings and push
// constants (the layout in sample_initial.comp's header; edges read-write, as the serial kernel reads them back for
// the positions) and the formula of edge k. Include after common/index.glsl and render/render_common.glsl.
layout(std430, binding = 0) readonly buffer Origins { float origins[]; };
layout(std430, binding = 1) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 2) buffer Edges { float edges[]; };
layout(std430, binding = 3) writeonly buffer Positions { float pos[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n; float near; float far; uint seed; uint step; uint level; uint jitter; uint contraction;
    uint ray_offset;
} pc;

// Edge k of a ray in s-space, given the ray's uniform u.
float edge_s(uint k, float u) {
    float inv = 1.0 / float(pc.n);
    float e = float(k) * inv;
    if (pc.jitter != 0u) {
        float lower = k == 0u ? 0.0 : e - 0.5 * inv;
        float upper = k == pc.n ? 1.0 : e + 0.5 * inv;
        e = lower + u * (upper - lower);
    }
    return e;
}
