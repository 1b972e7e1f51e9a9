// row_io.glsl: loads and stores of runs of consecutive floats in a row of a storage buffer, as wide as the run's
// alignment allows. On lavapipe every load or store whose address differs between invocations becomes a loop over
// the SIMD lanes; one 32-byte u64vec4 access per lane costs about as much as one float access, so reading 8 floats
// at a time is ~3-4x cheaper per float than reading them one by one (measured in docs/benchmarks.md). GPUs
// coalesce either form.
//
// ROWS_DECLARE(B, NAME, QUAL) declares binding B four times, as float NAME_1[], uint64_t NAME_2[], u64vec2 NAME_4[]
// and u64vec4 NAME_8[] (aliases of the same buffer, allowed for storage buffers of one descriptor type).
// ROWS_LOAD(NAME, VEC, base, dst, DOFF, COUNT): dst[DOFF + i] = NAME[base + i] for i < COUNT;
// ROWS_STORE(NAME, VEC, base, src, SOFF, COUNT): NAME[base + i] = src[SOFF + i] for i < COUNT.
// VEC (8, 4, 2 or 1 floats) must divide base; DOFF, SOFF and COUNT are compile-time constants (spec constants
// included), so the unrolled loops index dst/src with constants and the arrays stay in registers.
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

#define ROWS_DECLARE(B, NAME, QUAL) \
    layout(std430, binding = B) QUAL buffer NAME##_b1 { float NAME##_1[]; }; \
    layout(std430, binding = B) QUAL buffer NAME##_b2 { uint64_t NAME##_2[]; }; \
    layout(std430, binding = B) QUAL buffer NAME##_b4 { u64vec2 NAME##_4[]; }; \
    layout(std430, binding = B) QUAL buffer NAME##_b8 { u64vec4 NAME##_8[]; };

vec2 rows_unpack(uint64_t u) {
    return uintBitsToFloat(unpackUint2x32(u));
}

uint64_t rows_pack(float a, float b) {
    return packUint2x32(floatBitsToUint(vec2(a, b)));
}

// End of the part of a COUNT-float run covered by accesses of width W (given the width allowed and where the
// previous, wider accesses stopped).
#define ROWS_END(VEC, W, START, COUNT) ((VEC) >= (W) ? (START) + ((COUNT) - (START)) / (W) * (W) : (START))

// e8_, e4_, e2_: where the runs of 8-, 4- and 2-float accesses end in a COUNT-float run.
#define ROWS_SPLIT(VEC, COUNT) \
    uint e8_ = ROWS_END(VEC, 8u, 0u, COUNT); \
    uint e4_ = ROWS_END(VEC, 4u, e8_, COUNT); \
    uint e2_ = ROWS_END(VEC, 2u, e4_, COUNT);

#define ROWS_LOAD(NAME, VEC, base, dst, DOFF, COUNT) { \
    ROWS_SPLIT(VEC, COUNT) \
    uint b_ = (base); \
    [[unroll]] for (uint i_ = 0u; i_ < e8_; i_ += 8u) { \
        u64vec4 t_ = NAME##_8[(b_ + i_) / 8u]; \
        [[unroll]] for (uint c_ = 0u; c_ < 4u; ++c_) { \
            vec2 f_ = rows_unpack(t_[c_]); \
            dst[(DOFF) + i_ + 2u * c_] = f_.x; \
            dst[(DOFF) + i_ + 2u * c_ + 1u] = f_.y; \
        } \
    } \
    [[unroll]] for (uint i_ = e8_; i_ < e4_; i_ += 4u) { \
        u64vec2 t_ = NAME##_4[(b_ + i_) / 4u]; \
        vec2 f0_ = rows_unpack(t_.x), f1_ = rows_unpack(t_.y); \
        dst[(DOFF) + i_] = f0_.x; dst[(DOFF) + i_ + 1u] = f0_.y; \
        dst[(DOFF) + i_ + 2u] = f1_.x; dst[(DOFF) + i_ + 3u] = f1_.y; \
    } \
    [[unroll]] for (uint i_ = e4_; i_ < e2_; i_ += 2u) { \
        vec2 f_ = rows_unpack(NAME##_2[(b_ + i_) / 2u]); \
        dst[(DOFF) + i_] = f_.x; dst[(DOFF) + i_ + 1u] = f_.y; \
    } \
    [[unroll]] for (uint i_ = e2_; i_ < (COUNT); ++i_) dst[(DOFF) + i_] = NAME##_1[b_ + i_]; \
}

#define ROWS_STORE(NAME, VEC, base, src, SOFF, COUNT) { \
    ROWS_SPLIT(VEC, COUNT) \
    uint b_ = (base); \
    [[unroll]] for (uint i_ = 0u; i_ < e8_; i_ += 8u) { \
        uint s_ = (SOFF) + i_; \
        NAME##_8[(b_ + i_) / 8u] = u64vec4(rows_pack(src[s_], src[s_ + 1u]), rows_pack(src[s_ + 2u], src[s_ + 3u]), \
                                           rows_pack(src[s_ + 4u], src[s_ + 5u]), rows_pack(src[s_ + 6u], src[s_ + 7u])); \
    } \
    [[unroll]] for (uint i_ = e8_; i_ < e4_; i_ += 4u) { \
        uint s_ = (SOFF) + i_; \
        NAME##_4[(b_ + i_) / 4u] = u64vec2(rows_pack(src[s_], src[s_ + 1u]), rows_pack(src[s_ + 2u], src[s_ + 3u])); \
    } \
    [[unroll]] for (uint i_ = e4_; i_ < e2_; i_ += 2u) { \
        NAME##_2[(b_ + i_) / 2u] = rows_pack(src[(SOFF) + i_], src[(SOFF) + i_ + 1u]); \
    } \
    [[unroll]] for (uint i_ = e2_; i_ < (COUNT); ++i_) NAME##_1[b_ + i_] = src[(SOFF) + i_]; \
}

// Half-precision rows (hidden activations stored as fp16, MlpConfig::half_activations): the same buffers, read and
// written as pairs of halves packed in 32 bits (packHalf2x16 / unpackHalf2x16: core GLSL, no 16-bit storage feature
// needed; the arithmetic stays fp32). base, COUNT and VEC count halves: VEC (16, 8, 4 or 2) divides base, COUNT is
// even (every MLP width is a multiple of 16 and every block of one a multiple of 4).
// ROWS_LOAD_H(NAME, VEC, base, dst, DOFF, COUNT): dst[DOFF + i] = half NAME[base + i] for i < COUNT;
// ROWS_STORE_H(NAME, VEC, base, src, SOFF, COUNT): half NAME[base + i] = src[SOFF + i] for i < COUNT.

void rows_unpack_h4(uint64_t u, out vec4 f) {
    uvec2 p = unpackUint2x32(u);
    f = vec4(unpackHalf2x16(p.x), unpackHalf2x16(p.y));
}

uint64_t rows_pack_h4(float a, float b, float c, float d) {
    return packUint2x32(uvec2(packHalf2x16(vec2(a, b)), packHalf2x16(vec2(c, d))));
}

#define ROWS_SPLIT_H(VEC, COUNT) \
    uint e16_ = ROWS_END(VEC, 16u, 0u, COUNT); \
    uint e8h_ = ROWS_END(VEC, 8u, e16_, COUNT); \
    uint e4h_ = ROWS_END(VEC, 4u, e8h_, COUNT);

#define ROWS_LOAD_H(NAME, VEC, base, dst, DOFF, COUNT) { \
    ROWS_SPLIT_H(VEC, COUNT) \
    uint b_ = (base); \
    [[unroll]] for (uint i_ = 0u; i_ < e16_; i_ += 16u) { \
        u64vec4 t_ = NAME##_8[(b_ + i_) / 16u]; \
        [[unroll]] for (uint c_ = 0u; c_ < 4u; ++c_) { \
            vec4 f_; \
            rows_unpack_h4(t_[c_], f_); \
            [[unroll]] for (uint q_ = 0u; q_ < 4u; ++q_) dst[(DOFF) + i_ + 4u * c_ + q_] = f_[q_]; \
        } \
    } \
    [[unroll]] for (uint i_ = e16_; i_ < e8h_; i_ += 8u) { \
        u64vec2 t_ = NAME##_4[(b_ + i_) / 8u]; \
        vec4 f0_, f1_; \
        rows_unpack_h4(t_.x, f0_); \
        rows_unpack_h4(t_.y, f1_); \
        [[unroll]] for (uint q_ = 0u; q_ < 4u; ++q_) { \
            dst[(DOFF) + i_ + q_] = f0_[q_]; \
            dst[(DOFF) + i_ + 4u + q_] = f1_[q_]; \
        } \
    } \
    [[unroll]] for (uint i_ = e8h_; i_ < e4h_; i_ += 4u) { \
        vec4 f_; \
        rows_unpack_h4(NAME##_2[(b_ + i_) / 4u], f_); \
        [[unroll]] for (uint q_ = 0u; q_ < 4u; ++q_) dst[(DOFF) + i_ + q_] = f_[q_]; \
    } \
    [[unroll]] for (uint i_ = e4h_; i_ < (COUNT); i_ += 2u) { \
        vec2 f_ = unpackHalf2x16(floatBitsToUint(NAME##_1[(b_ + i_) / 2u])); \
        dst[(DOFF) + i_] = f_.x; dst[(DOFF) + i_ + 1u] = f_.y; \
    } \
}

#define ROWS_STORE_H(NAME, VEC, base, src, SOFF, COUNT) { \
    ROWS_SPLIT_H(VEC, COUNT) \
    uint b_ = (base); \
    [[unroll]] for (uint i_ = 0u; i_ < e16_; i_ += 16u) { \
        uint s_ = (SOFF) + i_; \
        NAME##_8[(b_ + i_) / 16u] = u64vec4( \
            rows_pack_h4(src[s_], src[s_ + 1u], src[s_ + 2u], src[s_ + 3u]), \
            rows_pack_h4(src[s_ + 4u], src[s_ + 5u], src[s_ + 6u], src[s_ + 7u]), \
            rows_pack_h4(src[s_ + 8u], src[s_ + 9u], src[s_ + 10u], src[s_ + 11u]), \
            rows_pack_h4(src[s_ + 12u], src[s_ + 13u], src[s_ + 14u], src[s_ + 15u])); \
    } \
    [[unroll]] for (uint i_ = e16_; i_ < e8h_; i_ += 8u) { \
        uint s_ = (SOFF) + i_; \
        NAME##_4[(b_ + i_) / 8u] = u64vec2(rows_pack_h4(src[s_], src[s_ + 1u], src[s_ + 2u], src[s_ + 3u]), \
                                           rows_pack_h4(src[s_ + 4u], src[s_ + 5u], src[s_ + 6u], src[s_ + 7u])); \
    } \
    [[unroll]] for (uint i_ = e8h_; i_ < e4h_; i_ += 4u) { \
        uint s_ = (SOFF) + i_; \
        NAME##_2[(b_ + i_) / 4u] = rows_pack_h4(src[s_], src[s_ + 1u], src[s_ + 2u], src[s_ + 3u]); \
    } \
    [[unroll]] for (uint i_ = e4h_; i_ < (COUNT); i_ += 2u) { \
        NAME##_1[(b_ + i_) / 2u] = uintBitsToFloat(packHalf2x16(vec2(src[(SOFF) + i_], src[(SOFF) + i_ + 1u]))); \
    } \
}

// Either form, by a (specialisation) constant: HALF != 0 reads halves (base, VEC in halves), else floats.
#define ROWS_LOAD_X(HALF, NAME, VEC, base, dst, DOFF, COUNT) \
    if ((HALF) != 0u) ROWS_LOAD_H(NAME, VEC, base, dst, DOFF, COUNT) else ROWS_LOAD(NAME, VEC, base, dst, DOFF, COUNT)
#define ROWS_STORE_X(HALF, NAME, VEC, base, src, SOFF, COUNT) \
    if ((HALF) != 0u) ROWS_STORE_H(NAME, VEC, base, src, SOFF, COUNT) else ROWS_STORE(NAME, VEC, base, src, SOFF, COUNT)

// ROWS_LOAD_TEX(TEX, base, dst, DOFF, COUNT): dst[DOFF + i] = float base + i of a buffer, for i < COUNT, read from
// TEX, an R32G32B32A32 texel view of that buffer (a uniform samplerBuffer; base a multiple of 4). A last partial
// texel reads floats past the run, inside the buffer: a view covers whole texels. On lavapipe a texelFetch at a
// per-lane index is a branch-free gather where a storage-buffer read is a loop over the lanes (src/gpu/texel.rs):
// the register-tile layers read their input rows so on CPU devices (`MlpTiling::texel_rows`, docs/benchmarks.md).
#define ROWS_LOAD_TEX(TEX, base, dst, DOFF, COUNT) { \
    int t_ = int((base) / 4u); \
    [[unroll]] for (uint i_ = 0u; i_ < (COUNT); i_ += 4u) { \
        vec4 v_ = texelFetch(TEX, t_ + int(i_ / 4u)); \
        [[unroll]] for (uint c_ = 0u; c_ < 4u; ++c_) if (i_ + c_ < (COUNT)) dst[(DOFF) + i_ + c_] = v_[c_]; \
    } \
}
