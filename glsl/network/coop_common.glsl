// coop_common.glsl: what mlp_coop_layer and mlp_coop_wgrad share: the 16 x 16 subgroup matrix types (fp16 operands,
// fp32 accumulators; VK_KHR_cooperative_matrix, the including kernel enables the extensions) and the power-of-two
// block scale that keeps small operands in fp16's normal range.

#define MAT_A coopmat<float16_t, gl_ScopeSubgroup, 16, 16, gl_MatrixUseA>
#define MAT_B coopmat<float16_t, gl_ScopeSubgroup, 16, 16, gl_MatrixUseB>
#define MAT_C coopmat<float, gl_ScopeSubgroup, 16, 16, gl_MatrixUseAccumulator>

// Power-of-two scale bringing a largest magnitude `mx` into [2^13, 2^14) (exact to apply and to undo); `fallback`
// for zero, NaN or Inf blocks, where there is nothing to gain.
float block_scale_for(float mx, float fallback) {
    if (!(mx > 0.0) || isinf(mx)) return fallback;
    int e;
    frexp(mx, e); // mx = f 2^e, f in [0.5, 1)
    return ldexp(1.0, clamp(14 - e, -100, 100));
}
