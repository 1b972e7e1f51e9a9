// hashgrid_entry.glsl: reading one table entry (F contiguous features) of a hash grid stored in a chunked large array.
// HASH_CHUNKED (spec constant, declared by the including kernel) = 0: the whole grid lies in one chunk whose device
// address the host passes directly; 1: the entry's chunk is looked up in the chunk table (one more per-lane load).
// An entry starts at a multiple of F and F divides 8, so it is read with one access of F floats (float, uint64,
// u64vec2 or u64vec4): on lavapipe a per-lane read costs about the same whatever its width up to 32 bytes.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer HashF1 { float v[]; };
layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer HashF2 { uint64_t v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer HashF4 { u64vec2 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 32) readonly buffer HashF8 { u64vec4 v[]; };

#ifndef HASH_TEXEL
// Device address and in-chunk offset (floats) of element g of the array `base` (a chunk address when
// HASH_CHUNKED = 0, the chunk table's address otherwise).
void hash_locate(uint64_t base, uint shift, uint g, out uint64_t addr, out uint o) {
    if (HASH_CHUNKED != 0u) {
        addr = large_chunk_addr(base, shift, g);
        o = large_offset(shift, g);
    } else {
        addr = base;
        o = g;
    }
}
#endif

#ifdef HASH_TEXEL
// The texel variant (build.rs defines HASH_TEXEL): the level's chunk bound as a uniform texel buffer at binding 12
// (R32, R32G32 or R32G32B32A32 SFLOAT for F = 1, 2, 4 and 8), read with texelFetch. On lavapipe a texel fetch is
// a gather without the per-lane branch of a read through a device address. `base` and `shift` are unused: the
// level lies in the bound chunk and g counts floats from the chunk's start (the variant declares no HASH_CHUNKED).
layout(binding = 12) uniform samplerBuffer hash_table;
#define HASH_ACCUMULATE_ENTRY(base, shift, g, wt_, acc) { \
    if (F == 1u) { \
        acc[0] += (wt_) * texelFetch(hash_table, int(g)).x; \
    } else if (F == 2u) { \
        vec2 t_ = texelFetch(hash_table, int((g) / 2u)).xy; \
        acc[0] += (wt_) * t_.x; acc[1 % F] += (wt_) * t_.y; \
    } else { \
        [[unroll]] for (uint q_ = 0u; q_ < F / 4u; ++q_) { \
            vec4 t_ = texelFetch(hash_table, int((g) / 4u + q_)); \
            acc[(4u * q_) % F] += (wt_) * t_.x; acc[(4u * q_ + 1u) % F] += (wt_) * t_.y; \
            acc[(4u * q_ + 2u) % F] += (wt_) * t_.z; acc[(4u * q_ + 3u) % F] += (wt_) * t_.w; \
        } \
    } \
}
#else
// acc[f] += w * entry[f] for the entry whose first float is element g.
#define HASH_ACCUMULATE_ENTRY(base, shift, g, w, acc) { \
    uint64_t a_; uint o_; \
    hash_locate(base, shift, g, a_, o_); \
    if (F == 1u) { \
        acc[0] += (w) * HashF1(a_).v[o_]; \
    } else if (F == 2u) { \
        vec2 t_ = rows_unpack(HashF2(a_).v[o_ / 2u]); \
        acc[0] += (w) * t_.x; acc[1 % F] += (w) * t_.y; \
    } else if (F == 4u) { \
        u64vec2 t_ = HashF4(a_).v[o_ / 4u]; \
        vec2 t0_ = rows_unpack(t_.x), t1_ = rows_unpack(t_.y); \
        acc[0] += (w) * t0_.x; acc[1 % F] += (w) * t0_.y; acc[2 % F] += (w) * t1_.x; acc[3 % F] += (w) * t1_.y; \
    } else { \
        u64vec4 t_ = HashF8(a_).v[o_ / 8u]; \
        [[unroll]] for (uint c_ = 0u; c_ < 4u; ++c_) { \
            vec2 tc_ = rows_unpack(t_[c_]); \
            acc[(2u * c_) % F] += (w) * tc_.x; acc[(2u * c_ + 1u) % F] += (w) * tc_.y; \
        } \
    } \
}
#endif
