// value_type.glsl: selects the element type of generic util kernels from a build-table define.
// VALUE_F32 -> float, VALUE_U32 -> uint (additions wrap modulo 2^32).
#if defined(VALUE_F32)
#define VALUE float
#define VALUE_ZERO 0.0
#elif defined(VALUE_U32)
#define VALUE uint
#define VALUE_ZERO 0u
#else
#error "define VALUE_F32 or VALUE_U32"
#endif
