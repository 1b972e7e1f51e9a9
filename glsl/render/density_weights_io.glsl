// density_weights_io.glsl: the bindings and push constants density_weights.comp and density_weights_lanes.comp
// share (the layout in density_weights.comp's header).
layout(std430, binding = 0) readonly buffer Edges { float edges[]; };
layout(std430, binding = 1) readonly buffer Raw { float raw[]; };
layout(std430, binding = 2) writeonly buffer Weights { float weights[]; };
layout(std430, binding = 3) readonly buffer Origins { float origins[]; };
layout(std430, binding = 4) readonly buffer Dirs { float dirs[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n; float near; float far; uint raw_stride; float density_scale; uint contraction;
} pc;
