// ray_lanes.glsl: one workgroup of LANES (32) invocations per ray, for the per-ray kernels on GPUs: a ray's samples
// go to the lanes in blocks of 32, and running sums over the samples become workgroup-wide prefix sums.
// The prefix sums are subgroup scans. A workgroup of 32 is one subgroup on NVIDIA (32-wide warps) and AMD; where
// subgroups are narrower (lavapipe: 8) the subgroups' totals are combined through shared memory. The lane of an
// invocation is gl_SubgroupID * gl_SubgroupSize + gl_SubgroupInvocationID, the order the scans follow.
// Every invocation of the workgroup must call the scans the same number of times (loop bounds uniform per ray).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#define LANES 32u

shared float lanes_partial[LANES];

uint lane_index() {
    return gl_SubgroupID * gl_SubgroupSize + gl_SubgroupInvocationID;
}

// Exclusive prefix sum of x over the workgroup's lanes, and the workgroup's total in `total`.
float lanes_exclusive_add(float x, out float total) {
    float excl = subgroupExclusiveAdd(x);
    float sum = subgroupAdd(x);
    if (gl_NumSubgroups == 1u) {
        total = sum;
        return excl;
    }
    barrier(); // the previous call's reads of lanes_partial are done
    if (subgroupElect()) lanes_partial[gl_SubgroupID] = sum;
    barrier();
    float before = 0.0;
    total = 0.0;
    for (uint s = 0u; s < gl_NumSubgroups; ++s) {
        float v = lanes_partial[s];
        if (s < gl_SubgroupID) before += v;
        total += v;
    }
    return before + excl;
}

// Workgroup-wide sum of x.
float lanes_add(float x) {
    float total;
    lanes_exclusive_add(x, total);
    return total;
}

shared uint lanes_partial_u[LANES];

// Workgroup-wide minimum of x.
uint lanes_min_u(uint x) {
    uint m = subgroupMin(x);
    if (gl_NumSubgroups == 1u) return m;
    barrier(); // the previous call's reads of lanes_partial_u are done
    if (subgroupElect()) lanes_partial_u[gl_SubgroupID] = m;
    barrier();
    uint r = 0xffffffffu;
    for (uint s = 0u; s < gl_NumSubgroups; ++s) r = min(r, lanes_partial_u[s]);
    return r;
}
