// activation.glsl: the MLP output activations, selected by the spec constant ACT that the including kernel declares:
// 0 none, 1 sigmoid, 2 exponential (backward derivative clamped as nerfstudio's trunc_exp: x in [-15, 15]), 3 ReLU.

float out_activation(float x) {
    if (ACT == 1u) return 1.0 / (1.0 + exp(-x));
    if (ACT == 2u) return exp(x);
    if (ACT == 3u) return max(x, 0.0);
    return x;
}

// d(activation)/dx expressed through the activation's output y.
float out_activation_grad(float y) {
    if (ACT == 1u) return y * (1.0 - y);
    if (ACT == 2u) return clamp(y, 3.059023205018258e-07, 3269017.372472111); // exp(clamp(x, -15, 15))
    if (ACT == 3u) return y > 0.0 ? 1.0 : 0.0;
    return 1.0;
}
