// mlp_common.glsl: specialisation constants and helpers shared by the fused MLP kernels (src/nn/mlp.rs).
// Network (tiny-cuda-nn FullyFusedMLP semantics, no biases): IN_PAD -> WIDTH (ReLU) -> ... -> WIDTH (ReLU) -> OUT_PAD,
// N_HIDDEN hidden layers, so N_HIDDEN + 1 matrices, stored row-major (W[j * in + k], j = output) one after another.
// The output activation OUT_ACT: 0 none, 1 sigmoid, 2 exponential (backward derivative clamped as trunc_exp: x in [-15, 15]),
// 3 ReLU.
layout(constant_id = 0) const uint WIDTH = 64;
layout(constant_id = 1) const uint IN_PAD = 32;
layout(constant_id = 2) const uint OUT_PAD = 16;
layout(constant_id = 3) const uint N_HIDDEN = 1;
layout(constant_id = 4) const uint OUT_ACT = 0;
layout(constant_id = 5) const uint ROWS = 4;
const uint MAXW_A = WIDTH > IN_PAD ? WIDTH : IN_PAD;
const uint MAXW = MAXW_A > OUT_PAD ? MAXW_A : OUT_PAD;

float out_activation(float x) {
    if (OUT_ACT == 1u) return 1.0 / (1.0 + exp(-x));
    if (OUT_ACT == 2u) return exp(x);
    if (OUT_ACT == 3u) return max(x, 0.0);
    return x;
}

// d(activation)/dx expressed through the activation's output y.
float out_activation_grad(float y) {
    if (OUT_ACT == 1u) return y * (1.0 - y);
    if (OUT_ACT == 2u) return clamp(y, 3.059023205018258e-07, 3269017.372472111); // exp(clamp(x, -15, 15))
    if (OUT_ACT == 3u) return y > 0.0 ? 1.0 : 0.0;
    return 1.0;
}
