// pose_common.glsl: nerfstudio's SO3xR3 camera correction (spec/nerfacto.md §2.4), shared by the pose kernels and
// mirrored in src/reference/pose.rs. A camera's correction is p = [t(3), w(3)]:
//   theta = sqrt(max(|w|^2, 1e-4)), a = sin(theta)/theta, b = (1 - cos(theta))/theta^2,
//   R d = d + a (w x d) + b (w x (w x d)),   origin' = origin + t,   direction' = R direction.
// b is evaluated as 2 sin^2(theta/2)/theta^2 (1 - cos(theta) cancels in fp32: 1e-3 relative error at the floor
// theta = 0.01); the derivatives use their Taylor series below theta = 0.1 (theta cos(theta) - sin(theta) cancels).
// da, db are (da/dtheta)/theta and (db/dtheta)/theta, so that d a / d w = da * w; both 0 on the floor, where theta
// does not depend on w.

void so3_coeffs(vec3 w, out float a, out float b, out float da, out float db) {
    float w2 = dot(w, w);
    bool floor_ = w2 < 1e-4;
    float th2 = floor_ ? 1e-4 : w2;
    float th = sqrt(th2);
    float s = sin(th), c = cos(th), h = sin(0.5 * th);
    a = s / th;
    b = 2.0 * h * h / th2;
    if (th < 0.1) {
        da = -1.0 / 3.0 + th2 * (1.0 / 30.0 - th2 * (1.0 / 840.0));
        db = -1.0 / 12.0 + th2 * (1.0 / 180.0 - th2 * (1.0 / 6720.0));
    } else {
        da = (th * c - s) / (th2 * th);
        db = (th * s - 4.0 * h * h) / (th2 * th2);
    }
    if (floor_) {
        da = 0.0;
        db = 0.0;
    }
}

vec3 so3_rotate(vec3 w, vec3 d) {
    float a, b, da, db;
    so3_coeffs(w, a, b, da, db);
    vec3 u = cross(w, d);
    return d + a * u + b * cross(w, u);
}

// dL/dw of direction' = R(w) d given g = dL/d(direction').
vec3 so3_rotate_grad_w(vec3 w, vec3 d, vec3 g) {
    float a, b, da, db;
    so3_coeffs(w, a, b, da, db);
    vec3 u = cross(w, d);
    vec3 v = cross(w, u); // w (w.d) - d |w|^2
    vec3 grad = a * cross(d, g) + b * (g * dot(w, d) + d * dot(g, w) - 2.0 * w * dot(g, d));
    return grad + (da * dot(g, u) + db * dot(g, v)) * w;
}

// dL/dx of a world point x given dL/dh of its hash input h (render_common.glsl `hash_input`): with contraction
// h = (contract(x) + 2)/4 and the contraction's Jacobian (the max-norm axis, first of equals, carries the extra term);
// without, h = (x + 1)/2 inside the box and no gradient outside.
vec3 hash_input_grad(vec3 x, vec3 gh, bool contraction) {
    if (!contraction) {
        vec3 p = (x + 1.0) * 0.5;
        bool inside = all(greaterThan(p, vec3(0.0))) && all(lessThan(p, vec3(1.0)));
        return inside ? 0.5 * gh : vec3(0.0);
    }
    vec3 g = 0.25 * gh;
    vec3 ax = abs(x);
    float m = max(max(ax.x, ax.y), ax.z);
    if (m < 1.0) return g;
    float k = (2.0 - 1.0 / m) / m;
    float dk = 2.0 * (1.0 - m) / (m * m * m);
    uint j = ax.x == m ? 0u : (ax.y == m ? 1u : 2u);
    vec3 out_ = k * g;
    out_[j] += sign(x[j]) * dk * dot(x, g);
    return out_;
}
