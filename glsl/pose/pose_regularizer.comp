// pose_regularizer: nerfstudio's camera-optimiser penalty (spec/nerfacto.md §2.4),
//   L = trans_weight * mean_c |t_c| + rot_weight * mean_c |w_c|   (plain norms, the mean over training cameras),
// its per-camera share written to `losses` and its gradient added to the pose slot of the gradient array
// (t_c / |t_c| scaled; 0 at |t_c| = 0, torch's subgradient). Each camera is owned by one invocation: no atomics.
// Twin: src/reference/pose.rs `regularizer`.
// Bindings: 0 per-camera loss (float[n_cams], written).
// Push:     params, grads (chunk-table addresses), shift, pose_offset, n_cams, inv_n_train, trans_weight, rot_weight.
// Threads:  one invocation per camera, 64 per group.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) writeonly buffer Losses { float losses[]; };
layout(push_constant) uniform Push {
    uint64_t params; uint64_t grads; uint shift; uint pose_offset; uint n_cams; float inv_n_train;
    float trans_weight; float rot_weight;
} pc;

void main() {
    uint c = global_index();
    if (c >= pc.n_cams) return;
    uint base = pc.pose_offset + 6u * c;
    float p[6];
    for (uint k = 0u; k < 6u; ++k) p[k] = large_load_f32(pc.params, pc.shift, base + k);
    vec3 t = vec3(p[0], p[1], p[2]), w = vec3(p[3], p[4], p[5]);
    float nt = length(t), nw = length(w);
    float wt = pc.trans_weight * pc.inv_n_train, wr = pc.rot_weight * pc.inv_n_train;
    losses[c] = wt * nt + wr * nw;
    vec3 gt = nt > 0.0 ? wt * t / nt : vec3(0.0);
    vec3 gw = nw > 0.0 ? wr * w / nw : vec3(0.0);
    for (uint k = 0u; k < 3u; ++k) {
        large_store_f32(pc.grads, pc.shift, base + k, large_load_f32(pc.grads, pc.shift, base + k) + gt[k]);
        large_store_f32(pc.grads, pc.shift, base + 3u + k, large_load_f32(pc.grads, pc.shift, base + 3u + k) + gw[k]);
    }
}
