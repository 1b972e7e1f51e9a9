//! The SO(3) exp map of nerfstudio's SO3xR3 camera correction (glsl/pose/pose_common.glsl): R(w) d by Rodrigues'
//! formula with theta = sqrt(max(|w|^2, 1e-4)), and its coefficients' derivatives for the backward pass.

use super::{c, cross, dot};
use num_traits::Float;

/// (a, b, da, db) of the exp map at w: R d = d + a (w x d) + b (w x (w x d)), with theta = sqrt(max(|w|^2, 1e-4));
/// da, db = (da/dtheta)/theta, (db/dtheta)/theta (0 on the floor; series below theta = 0.1, as pose_common.glsl).
pub fn so3_coeffs<T: Float>(w: [T; 3]) -> (T, T, T, T) {
    let w2 = dot(w, w);
    let on_floor = w2 < c(1e-4);
    let th2 = if on_floor { c(1e-4) } else { w2 };
    let th = th2.sqrt();
    // sin and 2 sin^2(theta/2) do not cancel; the derivatives do, so they use their series below theta = 0.1.
    let (s, co, h) = (th.sin(), th.cos(), (c::<T>(0.5) * th).sin());
    let (a, b) = (s / th, c::<T>(2.0) * h * h / th2);
    let (da, db) = if th < c(0.1) {
        (
            c::<T>(-1.0 / 3.0) + th2 * (c::<T>(1.0 / 30.0) - th2 * c(1.0 / 840.0)),
            c::<T>(-1.0 / 12.0) + th2 * (c::<T>(1.0 / 180.0) - th2 * c(1.0 / 6720.0)),
        )
    } else {
        ((th * co - s) / (th2 * th), (th * s - c::<T>(4.0) * h * h) / (th2 * th2))
    };
    if on_floor {
        (a, b, T::zero(), T::zero())
    } else {
        (a, b, da, db)
    }
}

/// R(w) d.
pub fn rotate<T: Float>(w: [T; 3], d: [T; 3]) -> [T; 3] {
    let (a, b, _, _) = so3_coeffs(w);
    let u = cross(w, d);
    let v = cross(w, u);
    [0, 1, 2].map(|k| d[k] + a * u[k] + b * v[k])
}
