// large_array.glsl: access to a logical array stored in chunks (src/gpu/large_array.rs), used for arrays larger
// than maxStorageBufferRange (128 MiB on lavapipe), e.g. Table 1's 256 MiB hash grid.
// The array is passed as the device address of its chunk table (one uint64 address per chunk) plus
// log2(elements per chunk); element i lives in chunk i >> shift at offset i & (2^shift - 1).
// Needs bufferDeviceAddress and shaderInt64 (both present on lavapipe and NVIDIA).
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer LargeChunkTable { uint64_t addr[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer LargeU32Chunk { uint v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer LargeF32Chunk { float v[]; };

uint64_t large_chunk_addr(uint64_t table, uint shift, uint i) {
    return LargeChunkTable(table).addr[i >> shift];
}

uint large_offset(uint shift, uint i) {
    return i & ((1u << shift) - 1u);
}

uint large_load_u32(uint64_t table, uint shift, uint i) {
    return LargeU32Chunk(large_chunk_addr(table, shift, i)).v[large_offset(shift, i)];
}

void large_store_u32(uint64_t table, uint shift, uint i, uint value) {
    LargeU32Chunk(large_chunk_addr(table, shift, i)).v[large_offset(shift, i)] = value;
}

float large_load_f32(uint64_t table, uint shift, uint i) {
    return LargeF32Chunk(large_chunk_addr(table, shift, i)).v[large_offset(shift, i)];
}

void large_store_f32(uint64_t table, uint shift, uint i, float value) {
    LargeF32Chunk(large_chunk_addr(table, shift, i)).v[large_offset(shift, i)] = value;
}
