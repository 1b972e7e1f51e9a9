// sh_grad.glsl: dL/d(direction) of the degree-4 SH encoding given dL/d(SH values) g[16] (sh_constants.glsl's basis):
// the partials of the polynomials as written (x, y, z independent, no projection onto the sphere). Shared by sh_bwd
// and the pose-refinement backward (glsl/pose/pose_ray_grad.comp); twin: src/reference/sh.rs `grad`.
// Needs encoding/sh_constants.glsl included first.
vec3 sh_direction_grad(vec3 d, float g[16]) {
    float x = d.x, y = d.y, z = d.z;
    float xy = x * y, xz = x * z, yz = y * z;
    float x2 = x * x, y2 = y * y, z2 = z * z;
    float a = 1.0 - 5.0 * z2;      // 1 - 5z^2
    float b = SH_3C9 * (y2 - x2);  // dY9/dy = dY15/dx
    float gx = g[3] * -SH_C1 + g[4] * (SH_C4 * y) + g[7] * (-SH_C4 * z) + g[8] * (SH_2C8 * x)
             + g[9] * (-SH_6C9 * xy) + g[10] * (SH_C10 * yz) + g[13] * (SH_C11 * a) + g[14] * (SH_2C14 * xz)
             + g[15] * b;
    float gy = g[1] * -SH_C1 + g[4] * (SH_C4 * x) + g[5] * (-SH_C4 * z) + g[8] * (-SH_2C8 * y) + g[9] * b
             + g[10] * (SH_C10 * xz) + g[11] * (SH_C11 * a) + g[14] * (-SH_2C14 * yz) + g[15] * (SH_6C9 * xy);
    float gz = g[2] * SH_C1 + g[5] * (-SH_C4 * y) + g[6] * (SH_2C6 * z) + g[7] * (-SH_C4 * x)
             + g[10] * (SH_C10 * xy) + g[11] * (-SH_10C11 * yz) + g[12] * (SH_C12 * (15.0 * z2 - 3.0))
             + g[13] * (-SH_10C11 * xz) + g[14] * (SH_C14 * (x2 - y2));
    return vec3(gx, gy, gz);
}
