// hashgrid_bwd_owned: the hash encoding's parameter gradient without atomics, for CPU devices (lavapipe). Each
// workgroup owns one level's range of the gradient array and is its only writer, so its adds are plain loads and
// stores, where hashgrid_bwd issues a float atomicAdd per contribution (on x86, a locked compare-and-swap loop per
// SIMD lane). The same sums as hashgrid_bwd (grad[entry, f] += weight * dL/dy[n, col + f] for every point, corner
// and feature), in another order. On lavapipe 1.1-1.4x on nerfacto's grids: the per-lane scattered accesses to
// the table, not the atomics, are most of either kernel's time (docs/benchmarks.md).
// Within the workgroup the 8 invocations are the 8 corners of one point: the points of the level are taken 8 at a
// time (each invocation reads one point's position and dL/dy), then one by one, broadcast to all 8 corners, which
// add into their entries. At a hashed level two corners of one point can hash to the same entry: every invocation
// hashes all 8 corners, and the first holding an entry adds the summed weights while the others skip. Points whose
// dL/dy is zero (masked-out samples) cost nothing past their read.
// Bindings: 0 positions (float[3N]), 1 levels (HashLevel[L]), 2 dL/dy (float rows of dy_stride).
// Push:     grads (address of the gradient array's chunk holding the whole grid), shift (unused), param_offset
//           (the grid's first float in that chunk), n, dy_stride, dy_col (level 0's first column; level l's are
//           F * l further), active_levels (coarse-to-fine: level l's dL/dy is multiplied by clamp(active_levels -
//           l, 0, 1); a held-back level's workgroup returns at once).
// Spec:     0 F.
// Threads:  one workgroup per level (x), of 8 invocations: the corners. The host uses it only where a workgroup of
//           8 is one subgroup (subgroup size 8 or more, with ballot), as on lavapipe; the levels' workgroups run in
//           parallel on the driver's threads.
#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_EXT_buffer_reference : require
#define WG_SIZE 8
#include "network/row_io.glsl"
#include "encoding/hashgrid_common.glsl"
layout(local_size_x = WG_SIZE) in;
layout(constant_id = 0) const uint F = 2;
layout(buffer_reference, std430, buffer_reference_align = 4) buffer GradF1 { float v[]; };
layout(buffer_reference, std430, buffer_reference_align = 8) buffer GradF2 { uint64_t v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) buffer GradF4 { u64vec2 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 32) buffer GradF8 { u64vec4 v[]; };
layout(std430, binding = 0) readonly buffer Positions { float pos[]; };
layout(std430, binding = 1) readonly buffer Levels { HashLevel levels[]; };
layout(std430, binding = 2) readonly buffer DLdy { float dy[]; };
layout(push_constant) uniform Push {
    uint64_t grads; uint shift; uint param_offset; uint n; uint dy_stride; uint dy_col; float active_levels;
} pc;

// grad[o + f] += add[f] for the entry whose first float is element o (one access of F floats each way).
void add_entry(uint o, float add[F]) {
    uint64_t a = pc.grads;
    if (F == 1u) {
        GradF1(a).v[o] += add[0];
    } else if (F == 2u) {
        vec2 t = rows_unpack(GradF2(a).v[o / 2u]);
        GradF2(a).v[o / 2u] = rows_pack(t.x + add[0], t.y + add[1 % F]);
    } else if (F == 4u) {
        u64vec2 t = GradF4(a).v[o / 4u];
        vec2 t0 = rows_unpack(t.x), t1 = rows_unpack(t.y);
        t.x = rows_pack(t0.x + add[0], t0.y + add[1 % F]);
        t.y = rows_pack(t1.x + add[2 % F], t1.y + add[3 % F]);
        GradF4(a).v[o / 4u] = t;
    } else {
        u64vec4 t = GradF8(a).v[o / 8u];
        [[unroll]] for (uint c = 0u; c < 4u; ++c) {
            vec2 tc = rows_unpack(t[c]);
            t[c] = rows_pack(tc.x + add[(2u * c) % F], tc.y + add[(2u * c + 1u) % F]);
        }
        GradF8(a).v[o / 8u] = t;
    }
}

void main() {
    uint l = gl_WorkGroupID.x;
    uint corner = gl_SubgroupInvocationID;
    HashLevel lv = levels[l];
    float weight = clamp(pc.active_levels - float(l), 0.0, 1.0);
    if (weight == 0.0) return; // a held-back level gets no gradient
    uint first = pc.param_offset + lv.offset * F;
    uint col = pc.dy_col + l * F;
    for (uint base = 0u; base < pc.n; base += 8u) {
        // This invocation's point of the next 8: position and weighted dL/dy (zero past the end).
        uint i = base + corner;
        vec3 p = vec3(0.0);
        float g[F];
        [[unroll]] for (uint f = 0u; f < F; ++f) g[f] = 0.0;
        if (i < pc.n) {
            p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
            [[unroll]] for (uint f = 0u; f < F; ++f) g[f] = weight * dy[i * pc.dy_stride + col + f];
        }
        [[unroll]] for (uint j = 0u; j < 8u; ++j) {
            float gj[F];
            bool any_nonzero = false;
            [[unroll]] for (uint f = 0u; f < F; ++f) {
                gj[f] = subgroupBroadcast(g[f], j);
                any_nonzero = any_nonzero || gj[f] != 0.0;
            }
            if (!any_nonzero) continue; // uniform: the value is the same in every invocation
            uvec3 cell;
            vec3 frac;
            hash_cell(lv, subgroupBroadcast(p, j), cell, frac);
            uint e = hash_index(lv, corner_vertex(corner, cell));
            float w = corner_weight(corner, frac);
            bool writer = true;
            if (lv.hashed != 0u) {
                // Corners sharing an entry: the first adds their summed weights, the others nothing. Every
                // invocation hashes all 8 corners itself (cheaper on lavapipe than 8 broadcasts and a vote).
                w = 0.0;
                [[unroll]] for (uint k = 0u; k < 8u; ++k) {
                    bool same = hash_index_known(lv, corner_vertex(k, cell), true) == e;
                    w += same ? corner_weight(k, frac) : 0.0;
                    writer = writer && !(k < corner && same);
                }
            }
            float add[F];
            [[unroll]] for (uint f = 0u; f < F; ++f) add[f] = w * gj[f];
            if (writer) add_entry(first + e * F, add);
            // The next point's corners may read what this one's wrote (neighbouring cells share vertices).
            subgroupMemoryBarrierBuffer();
            subgroupBarrier();
        }
    }
}
