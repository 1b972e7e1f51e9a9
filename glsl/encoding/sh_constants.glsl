// sh_constants.glsl: coefficients of the degree-4 real SH basis in tiny-cuda-nn's convention (nerfacto.md §2.16),
// shared by sh_fwd and sh_bwd and mirrored in src/reference/sh.rs. Products used by the backward are folded
// here from the f64 values.
// Values per direction (degree 4); equals `nn::sh::SH_DIM`, which a unit test there checks.
const uint SH_DIM = 16u;
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

// The 16 basis values at unit direction d (tiny-cuda-nn order and signs).
void sh_eval(vec3 d, out float sh[16]) {
    float x = d.x, y = d.y, z = d.z;
    float xy = x * y, xz = x * z, yz = y * z;
    float x2 = x * x, y2 = y * y, z2 = z * z;
    sh[0] = SH_C0;
    sh[1] = -SH_C1 * y;
    sh[2] = SH_C1 * z;
    sh[3] = -SH_C1 * x;
    sh[4] = SH_C4 * xy;
    sh[5] = -SH_C4 * yz;
    sh[6] = SH_C6 * z2 - SH_C6B;
    sh[7] = -SH_C4 * xz;
    sh[8] = SH_C8 * (x2 - y2);
    sh[9] = SH_C9 * y * (y2 - 3.0 * x2);
    sh[10] = SH_C10 * xy * z;
    sh[11] = SH_C11 * y * (1.0 - 5.0 * z2);
    sh[12] = SH_C12 * z * (5.0 * z2 - 3.0);
    sh[13] = SH_C11 * x * (1.0 - 5.0 * z2);
    sh[14] = SH_C14 * z * (x2 - y2);
    sh[15] = SH_C9 * x * (3.0 * y2 - x2);
}
