// interlevel_io.glsl: what interlevel.comp and interlevel_lanes.comp share: their bindings and push constants (the
// layout in interlevel.comp's header) and a proposal sample's density (zero outside the box without contraction).
// Include after common/index.glsl and render/render_common.glsl.
layout(std430, binding = 0) readonly buffer NerfEdges { float c[]; };
layout(std430, binding = 1) readonly buffer NerfWeights { float w[]; };
layout(std430, binding = 2) readonly buffer PropEdges { float cp[]; };
layout(std430, binding = 3) readonly buffer PropRaw { float raw[]; };
layout(std430, binding = 4) buffer PropWeights { float wp[]; };
layout(std430, binding = 5) buffer PropDy { float dy[]; };
layout(std430, binding = 6) writeonly buffer Losses { float losses[]; };
layout(std430, binding = 7) readonly buffer Origins { float origins[]; };
layout(std430, binding = 8) readonly buffer Dirs { float dirs[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n_nerf; uint n_prop; float near; float far; uint raw_stride; float density_scale; float norm;
    uint contraction;
} pc;

float prop_sigma(uint r, uint j, vec3 o, vec3 d, float tmid) {
    return density_at(raw[(r * pc.n_prop + j) * pc.raw_stride], pc.density_scale, o + d * tmid, pc.contraction != 0u);
}
