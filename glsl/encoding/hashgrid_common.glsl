// hashgrid_common.glsl: the multiresolution hash grid's level table and corner enumeration (tiny-cuda-nn semantics,
// spec/nerfacto.md §3): q = scale_l * p + 0.5, cell = floor(q), frac = q - cell; dense index x + y*res + z*res^2 for
// levels that fit, CoherentPrime hash (1, 2654435761, 805459861) otherwise; index modulo the level's entry count.
// Parameters are entry-major (F contiguous floats per entry) inside a chunked large array (common/large_array.glsl);
// F divides the power-of-two chunk size and entries start at multiples of F, so one entry never straddles chunks.

struct HashLevel {
    float scale;   // 2^(l log2 b) * N_min - 1
    uint res;      // vertices per axis
    uint entries;  // table entries of this level (multiple of 8; power of two when hashed)
    uint offset;   // first entry of this level, counted from the grid's first entry
    uint hashed;   // 1: CoherentPrime hash, 0: dense
    uint pad0;
    uint pad1;
    uint pad2;
};

uint hash_index(HashLevel lv, uvec3 v) {
    uint idx;
    if (lv.hashed != 0u) {
        idx = (v.x * 1u) ^ (v.y * 2654435761u) ^ (v.z * 805459861u);
        return idx & (lv.entries - 1u);
    }
    idx = v.x + v.y * lv.res + v.z * lv.res * lv.res;
    return idx % lv.entries;
}

// The same with the level's kind known at compile time (kernels that unroll the levels: no branch, and the dense
// modulo without an integer division, which x86 SIMD lacks: a float quotient, exact after one correction step since
// indices stay below 2^24).
uint hash_index_known(HashLevel lv, uvec3 v, bool hashed) {
    if (hashed) {
        return ((v.x * 1u) ^ (v.y * 2654435761u) ^ (v.z * 805459861u)) & (lv.entries - 1u);
    }
    uint idx = v.x + v.y * lv.res + v.z * lv.res * lv.res;
    int r = int(idx) - int(lv.entries) * int(floor(float(idx) / float(lv.entries)));
    r += r < 0 ? int(lv.entries) : 0;
    r -= r >= int(lv.entries) ? int(lv.entries) : 0;
    return uint(r);
}

// Cell and fractional position of p (in [0,1]^3) at a level. q is clamped at 0 so points a hair outside the unit
// cube (contraction rounding) cannot wrap the unsigned cell index.
void hash_cell(HashLevel lv, vec3 p, out uvec3 cell, out vec3 frac) {
    vec3 q = max(p * lv.scale + 0.5, vec3(0.0));
    vec3 fl = floor(q);
    cell = uvec3(fl);
    frac = q - fl;
}

// Trilinear weight of corner c (bit d of c selects cell+1 along axis d).
float corner_weight(uint c, vec3 frac) {
    float w = 1.0;
    for (uint d = 0u; d < 3u; ++d) {
        w *= ((c >> d) & 1u) != 0u ? frac[d] : 1.0 - frac[d];
    }
    return w;
}

uvec3 corner_vertex(uint c, uvec3 cell) {
    return cell + uvec3(c & 1u, (c >> 1u) & 1u, (c >> 2u) & 1u);
}
