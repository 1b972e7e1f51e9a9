// ray_gen: world rays through pixel centres (spec/nerfacto.md §2.3; twin: src/data/camera.rs `generate_ray`):
// normalised image coordinates, OPENCV undistortion by Newton's method (10 iterations, steps only where |det J| > 1e-3),
// OpenGL flip (y up, looking along -z), fisheye mapping, rotation to world, unit direction. Model 3 (orthographic,
// nerfstudio's ORTHOPHOTO): parallel rays along the camera's -z from the centre moved by R (x, -y, 0).
// Bindings: 0 cameras (GpuCamera[]), 1 pixels (uint[3R]: camera, row, col), 2 origins (float[3R], written),
//           3 directions (float[3R], written), 4 direction norms (float[R], written: |(x, y, -1)| before normalising).
// Push:     n_rays.
// Threads:  one invocation per ray, 64 per group, folded into 2D past 65535 groups.
#version 460
#define WG_SIZE 64
#include "common/index.glsl"
layout(local_size_x = WG_SIZE) in;

struct GpuCamera {
    float fx, fy, cx, cy;
    float k1, k2, k3, k4, p1, p2;
    uint model;     // 0 pinhole, 1 OPENCV, 2 OPENCV_FISHEYE, 3 orthographic
    uint distorted; // 1 when any distortion coefficient is non-zero (and the model is not pinhole)
    float c2w[12];  // 3x4 row-major camera-to-world (normalised frame)
};

layout(std430, binding = 0) readonly buffer Cameras { GpuCamera cams[]; };
layout(std430, binding = 1) readonly buffer Pixels { uint pixels[]; };
layout(std430, binding = 2) writeonly buffer Origins { float origins[]; };
layout(std430, binding = 3) writeonly buffer Dirs { float dirs[]; };
layout(std430, binding = 4) writeonly buffer Norms { float norms[]; };
layout(push_constant) uniform Push { uint n_rays; } pc;

vec2 undistort(vec2 pd, GpuCamera c) {
    float x = pd.x, y = pd.y;
    for (uint it = 0u; it < 10u; ++it) {
        float r = x * x + y * y;
        float d = 1.0 + r * (c.k1 + r * (c.k2 + r * (c.k3 + r * c.k4)));
        float fx = d * x + 2.0 * c.p1 * x * y + c.p2 * (r + 2.0 * x * x) - pd.x;
        float fy = d * y + 2.0 * c.p2 * x * y + c.p1 * (r + 2.0 * y * y) - pd.y;
        float d_r = c.k1 + r * (2.0 * c.k2 + r * (3.0 * c.k3 + r * 4.0 * c.k4));
        float d_x = 2.0 * x * d_r;
        float d_y = 2.0 * y * d_r;
        float fx_x = d + d_x * x + 2.0 * c.p1 * y + 6.0 * c.p2 * x;
        float fx_y = d_y * x + 2.0 * c.p1 * x + 2.0 * c.p2 * y;
        float fy_x = d_x * y + 2.0 * c.p2 * y + 2.0 * c.p1 * x;
        float fy_y = d + d_y * y + 2.0 * c.p2 * x + 6.0 * c.p1 * y;
        float den = fy_x * fx_y - fx_x * fy_y;
        if (abs(den) > 1e-3) {
            x += (fx * fy_y - fy * fx_y) / den;
            y += (fy * fx_x - fx * fy_x) / den;
        }
    }
    return vec2(x, y);
}

void main() {
    uint r = global_index();
    if (r >= pc.n_rays) return;
    GpuCamera c = cams[pixels[3u * r]];
    float v = float(pixels[3u * r + 1u]) + 0.5;
    float u = float(pixels[3u * r + 2u]) + 0.5;
    vec2 p = vec2((u - c.cx) / c.fx, (v - c.cy) / c.fy);
    if (c.distorted != 0u) p = undistort(p, c);
    p.y = -p.y;
    vec3 d = vec3(p, -1.0);
    vec3 o = vec3(c.c2w[3], c.c2w[7], c.c2w[11]);
    if (c.model == 3u) {
        o += vec3(c.c2w[0] * p.x + c.c2w[1] * p.y, c.c2w[4] * p.x + c.c2w[5] * p.y, c.c2w[8] * p.x + c.c2w[9] * p.y);
        d = vec3(0.0, 0.0, -1.0);
    }
    if (c.model == 2u) {
        float theta = min(length(p), 3.14159265358979);
        float s = theta > 1e-12 ? sin(theta) / theta : 1.0;
        d = vec3(p * s, -cos(theta));
    }
    vec3 w = vec3(c.c2w[0] * d.x + c.c2w[1] * d.y + c.c2w[2] * d.z,
                  c.c2w[4] * d.x + c.c2w[5] * d.y + c.c2w[6] * d.z,
                  c.c2w[8] * d.x + c.c2w[9] * d.y + c.c2w[10] * d.z);
    float n = length(w);
    origins[3u * r] = o.x;
    origins[3u * r + 1u] = o.y;
    origins[3u * r + 2u] = o.z;
    dirs[3u * r] = w.x / n;
    dirs[3u * r + 1u] = w.y / n;
    dirs[3u * r + 2u] = w.z / n;
    norms[r] = n;
}
