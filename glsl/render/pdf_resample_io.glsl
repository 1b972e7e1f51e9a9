// pdf_resample_io.glsl: what pdf_resample.comp and pdf_resample_lanes.comp share: their bindings and push constants
// (the layout in pdf_resample.comp's header; edges out read-write, as the serial kernel reads them back) and the
// padded, annealed weight of a bin. Include after common/index.glsl and render/render_common.glsl.
layout(std430, binding = 0) readonly buffer EdgesIn { float edges_in[]; };
layout(std430, binding = 1) readonly buffer Weights { float weights[]; };
layout(std430, binding = 2) buffer EdgesOut { float edges_out[]; };
layout(std430, binding = 3) writeonly buffer Positions { float pos[]; };
layout(std430, binding = 4) readonly buffer Origins { float origins[]; };
layout(std430, binding = 5) readonly buffer Dirs { float dirs[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n; uint m; float near; float far; float anneal; uint seed; uint step; uint level; uint jitter;
    uint contraction; uint ray_offset;
} pc;

float padded_weight(uint r, uint i) {
    float w = max(weights[r * pc.n + i], 0.0);
    float a = w == 0.0 && pc.anneal == 0.0 ? 1.0 : pow(w, pc.anneal);
    return a + 0.01;
}
