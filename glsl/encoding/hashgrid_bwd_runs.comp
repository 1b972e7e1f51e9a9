// hashgrid_bwd_runs: hashgrid_bwd's gradient with run combining, the alternative to one atomic per contribution that
// docs/benchmarks.md measures: slower on lavapipe, 1.1-1.9x faster on an H100, where atomic contention on coarse
// levels costs more; the default on GPUs (`nn::hashgrid::default_backward_run`). An invocation takes RUN
// consecutive points (the samples of a ray are consecutive) and adds up, in registers, the contributions of points
// that fall in the same cell as the point before, issuing the 8 x F atomics once per run of equal cells instead of
// once per point. Coarse levels, where many samples of a ray share a cell, need far fewer atomics.
// Bindings: 0 positions (float[3N]), 1 levels (HashLevel[L]), 2 dL/dy (float rows of dy_stride).
// Push:     grads (chunk-table address), shift, param_offset, n, dy_stride, dy_col, active_levels (coarse-to-fine:
//           level l's dL/dy is multiplied by clamp(active_levels - l, 0, 1), the per-level kernels' weight; L or more
//           for all levels).
// Spec:     0 F, 1 RUN.
// Threads:  one invocation per (RUN points, level): x (folded into 2D) over point runs, z over levels; 128 per group.
#version 460
#extension GL_EXT_shader_atomic_float : require
#define WG_SIZE 128
#include "common/index.glsl"
#include "common/large_array.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(constant_id = 1) const uint RUN = 1;
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
layout(std430, binding = 1) readonly buffer Levels { HashLevel levels[]; };
layout(std430, binding = 2) readonly buffer DLdy { float dy[]; };
layout(push_constant) uniform Push {
    uint64_t grads; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; float active_levels;
} pc;

float acc[8 * F]; // the open run's sums, per corner and feature

// Adds acc to the entries of the corners of `cell`.
void flush(HashLevel lv, uvec3 cell) {
    for (uint c = 0u; c < 8u; ++c) {
        uint e = pc.param_offset + (lv.offset + hash_index(lv, corner_vertex(c, cell))) * F;
        LargeF32Chunk chunk = LargeF32Chunk(large_chunk_addr(pc.grads, pc.shift, e));
        uint o = large_offset(pc.shift, e);
        for (uint f = 0u; f < F; ++f) atomicAdd(chunk.v[o + f], acc[c * F + f]);
    }
}

void main() {
    uint i0 = global_index() * RUN;
    uint l = gl_WorkGroupID.z;
    if (i0 >= pc.n) return;
    HashLevel lv = levels[l];
    float weight = clamp(pc.active_levels - float(l), 0.0, 1.0);
    if (weight == 0.0) return; // a held-back level gets no gradient
    uvec3 cur = uvec3(0u);
    bool open_run = false;
    for (uint r = 0u; r < RUN; ++r) {
        uint i = i0 + r;
        if (i >= pc.n) break;
        float g[F];
        bool any_nonzero = false;
        for (uint f = 0u; f < F; ++f) {
            g[f] = weight * dy[i * pc.dy_stride + pc.dy_col + l * F + f];
            any_nonzero = any_nonzero || g[f] != 0.0;
        }
        if (!any_nonzero) continue; // masked-out samples cost no atomics
        vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
        uvec3 cell;
        vec3 frac;
        hash_cell(lv, p, cell, frac);
        if (open_run && cell != cur) {
            flush(lv, cur);
            open_run = false;
        }
        if (!open_run) {
            for (uint k = 0u; k < 8u * F; ++k) acc[k] = 0.0;
            cur = cell;
            open_run = true;
        }
        for (uint c = 0u; c < 8u; ++c) {
            float w = corner_weight(c, frac);
            for (uint f = 0u; f < F; ++f) acc[c * F + f] += w * g[f];
        }
    }
    if (open_run) flush(lv, cur);
}
