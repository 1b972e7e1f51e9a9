// appearance_grad: gradient of the per-image appearance embeddings: for every ray r and dimension k,
// grad_emb[cam[r]][k] += sum over the ray's n NeRF samples s of dx[s * dx_stride + dx_col + k]. The samples of a ray
// share its camera, so an invocation sums them in registers first and issues one fp32 atomicAdd (through the
// gradient array's chunk table; the embedding slot lies inside one chunk) per (ray, k) instead of one per
// (sample, k): n times fewer atomics (48 with nerfacto), which on lavapipe are a per-lane compare-and-swap loop.
// Runs only when the model has appearance embeddings.
// Bindings: 0 dL/d(colour input) rows, 1 camera index per ray (uint[R]).
// Push:     grads (chunk-table address), shift, emb_offset (first float of the embedding slot), n_rays, n (samples
//           per ray), dim, dx_stride, dx_col.
// Threads:  one invocation per (ray, embedding dimension), k fastest, 256 per group, folded into 2D past 65535
//           groups.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer DX { float dx[]; };
layout(std430, binding = 1) readonly buffer CamIdx { uint cam_idx[]; };
layout(push_constant) uniform Push {
    uint64_t grads; uint shift; uint emb_offset; uint n_rays; uint n; uint dim; uint dx_stride; uint dx_col;
} pc;

void main() {
    uint e = global_index();
    if (e >= pc.n_rays * pc.dim) return;
    uint r = e / pc.dim, k = e % pc.dim;
    float g = 0.0;
    uint at = r * pc.n * pc.dx_stride + pc.dx_col + k;
    for (uint s = 0u; s < pc.n; ++s) {
        g += dx[at];
        at += pc.dx_stride;
    }
    if (g == 0.0) return; // a ray whose samples carry no gradient (masked out) costs no atomic
    uint idx = pc.emb_offset + cam_idx[r] * pc.dim + k;
    LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, idx));
    atomicAdd(chunk.v[large_offset(pc.shift, idx)], g);
}
