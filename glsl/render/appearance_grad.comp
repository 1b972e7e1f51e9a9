// appearance_grad: gradient of the per-image appearance embeddings: for every NeRF sample s of ray r,
// grad_emb[cam[r]][k] += dx[s * dx_stride + dx_col + k] for k < dim (fp32 atomicAdd through the gradient array's
// chunk table; the embedding slot lies inside one chunk). Runs only when the model has appearance embeddings.
// Bindings: 0 dL/d(colour input) rows, 1 camera index per ray (uint[R]).
// Push:     grads (chunk-table address), shift, emb_offset (first float of the embedding slot), n_samples, n (per ray),
//           dim, dx_stride, dx_col.
// Threads:  one invocation per (sample, embedding dimension), 256 per group, folded into 2D past 65535 groups.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 256
#include "common/index.glsl"
#include "common/large_array.glsl"
layout(local_size_x = WG_SIZE) in;
layout(std430, binding = 0) readonly buffer DX { float dx[]; };
layout(std430, binding = 1) readonly buffer CamIdx { uint cam_idx[]; };
layout(push_constant) uniform Push {
    uint64_t grads; uint shift; uint emb_offset; uint n_samples; uint n; uint dim; uint dx_stride; uint dx_col;
} pc;

void main() {
    uint e = global_index();
    if (e >= pc.n_samples * pc.dim) return;
    uint s = e / pc.dim, k = e % pc.dim;
    float g = dx[s * pc.dx_stride + pc.dx_col + k];
    if (g == 0.0) return;
    uint idx = pc.emb_offset + cam_idx[s / pc.n] * pc.dim + k;
    LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, idx));
    atomicAdd(chunk.v[large_offset(pc.shift, idx)], g);
}
