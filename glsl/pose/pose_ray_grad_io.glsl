// pose_ray_grad_io.glsl: the bindings and push constants pose_ray_grad.comp and pose_ray_grad_lanes.comp share (the
// layout in pose_ray_grad.comp's header).
layout(std430, binding = 0) readonly buffer Origins { float origins[]; };
layout(std430, binding = 1) readonly buffer Dirs { float dirs[]; };
layout(std430, binding = 2) readonly buffer Edges { float edges[]; };
layout(std430, binding = 3) readonly buffer DPos { float dpos[]; };
layout(std430, binding = 4) readonly buffer ColourDx { float cdx[]; };
layout(std430, binding = 5) buffer RayGrad { float ray_grad[]; };
layout(push_constant) uniform Push {
    uint n_rays; uint n; float near; float far; uint contraction; uint accumulate; uint sh; uint dx_stride;
} pc;
