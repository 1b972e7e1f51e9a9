// sh_constants.glsl: coefficients of the degree-4 real SH basis in tiny-cuda-nn's convention (nerfacto.md §2.16),
// shared by sh_fwd and sh_bwd and mirrored in src/reference/sh.rs. Products used by the backward are folded
// here from the f64 values.
const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.48860251190291987;
const float SH_C4 = 1.0925484305920792;
const float SH_C6 = 0.94617469575755997;
const float SH_C6B = 0.31539156525251999;
const float SH_C8 = 0.54627421529603959;
const float SH_C9 = 0.59004358992664352;
const float SH_C10 = 2.8906114426405538;
const float SH_C11 = 0.45704579946446572;
const float SH_C12 = 0.3731763325901154;
const float SH_C14 = 1.4453057213202769;
const float SH_2C6 = 1.89234939151512;      // 2 * C6
const float SH_2C8 = 1.0925484305920792;    // 2 * C8
const float SH_3C9 = 1.7701307697799304;    // 3 * C9
const float SH_6C9 = 3.540261539559861;     // 6 * C9
const float SH_10C11 = 4.5704579946446575;  // 10 * C11
const float SH_2C14 = 2.890611442640554;    // 2 * C14
