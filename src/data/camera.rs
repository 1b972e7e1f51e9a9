//! Camera models and CPU ray generation, the CPU twin of the GPU ray-generation kernel (spec/nerfacto.md §2.3).
//!
//! Pure functions of (camera, pose, pixel), generic over f32 and f64 ([`Real`]):
//! 1. pixel centre (u, v) = (col + 0.5, row + 0.5); normalised x = (u − cx)/fx, y = (v − cy)/fy (y down);
//! 2. OPENCV / OPENCV_FISHEYE: undistort by Newton's method, at most 10 iterations from the distorted point,
//!    a step taken only where |det J| > 1e-3; distortion d = 1 + k1 r + k2 r² + k3 r³ + k4 r⁴ with r = x² + y²;
//! 3. flip to OpenGL (y ← −y), camera direction (x, y, −1) (fisheye: (x sinθ/θ, y sinθ/θ, −cosθ), θ = |(x,y)|
//!    clipped to [0, π]);
//! 4. world direction = R_c2w · dir, normalised; its norm before normalising is kept in `direction_norm`.
//!
//! `Orthographic` (parallel rays, nerfstudio's ORTHOPHOTO) skips 2-3: origin = centre + R_c2w · (x, −y, 0) with
//! x, y of step 1, direction R_c2w · (0, 0, −1).

use serde::{Deserialize, Serialize};

/// Projection model (dataset.md `camera_model`; SIMPLE_PINHOLE maps to `Pinhole`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CameraModel {
    Pinhole,
    OpenCv,
    OpenCvFisheye,
    /// Parallel rays (nerfstudio's `CameraType.ORTHOPHOTO`): pixel (u, v) starts at the camera centre plus
    /// ((u - cx) / fx, -(v - cy) / fy, 0) in camera axes and looks along the camera's -z. fx, fy are pixels per
    /// unit of the frame the pose is in. Not a dataset `camera_model`: the survey exports (DSM, true ortho) use it.
    Orthographic,
}

/// Distortion coefficients; missing ones are 0.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub k4: f64,
    pub p1: f64,
    pub p2: f64,
}

impl Distortion {
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.k3, self.k4, self.p1, self.p2].iter().all(|&v| v == 0.0)
    }
    /// As `[k1, k2, k3, k4, p1, p2]` in `T`.
    pub fn params<T: Real>(&self) -> [T; 6] {
        [self.k1, self.k2, self.k3, self.k4, self.p1, self.p2].map(T::from_f64)
    }
}

/// Intrinsics of one image (pixels).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub model: CameraModel,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
    pub distortion: Distortion,
}

/// A ray in world (or normalised) space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray<T> {
    pub origin: [T; 3],
    /// Unit length.
    pub direction: [T; 3],
    /// Length of the world direction before normalisation (for z-depth ↔ ray-distance conversion).
    pub direction_norm: T,
}

/// The float operations ray generation needs; implemented for f32 and f64.
pub trait Real:
    Copy
    + PartialOrd
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    fn from_f64(v: f64) -> Self;
    fn sqrt(self) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn abs(self) -> Self;
}

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            #[inline]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);

/// Forward distortion of normalised coordinates (y down), params `[k1, k2, k3, k4, p1, p2]`.
#[inline]
pub fn distort<T: Real>(x: T, y: T, p: &[T; 6]) -> (T, T) {
    let [k1, k2, k3, k4, p1, p2] = *p;
    let one = T::from_f64(1.0);
    let two = T::from_f64(2.0);
    let r = x * x + y * y;
    let d = one + r * (k1 + r * (k2 + r * (k3 + r * k4)));
    (x * d + two * p1 * x * y + p2 * (r + two * x * x), y * d + two * p2 * x * y + p1 * (r + two * y * y))
}

/// Newton undistortion exactly as nerfstudio's `radial_and_tangential_undistort` (10 iterations, eps 1e-3).
#[inline]
pub fn undistort<T: Real>(xd: T, yd: T, p: &[T; 6]) -> (T, T) {
    let [k1, k2, k3, k4, p1, p2] = *p;
    let one = T::from_f64(1.0);
    let two = T::from_f64(2.0);
    let three = T::from_f64(3.0);
    let four = T::from_f64(4.0);
    let six = T::from_f64(6.0);
    let eps = T::from_f64(1e-3);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..10 {
        let r = x * x + y * y;
        let d = one + r * (k1 + r * (k2 + r * (k3 + r * k4)));
        let fx = d * x + two * p1 * x * y + p2 * (r + two * x * x) - xd;
        let fy = d * y + two * p2 * x * y + p1 * (r + two * y * y) - yd;
        let d_r = k1 + r * (two * k2 + r * (three * k3 + r * four * k4));
        let d_x = two * x * d_r;
        let d_y = two * y * d_r;
        let fx_x = d + d_x * x + two * p1 * y + six * p2 * x;
        let fx_y = d_y * x + two * p1 * x + two * p2 * y;
        let fy_x = d_x * y + two * p2 * y + two * p1 * x;
        let fy_y = d + d_y * y + two * p2 * x + six * p1 * y;
        let den = fy_x * fx_y - fx_x * fy_y;
        if den.abs() > eps {
            x = x + (fx * fy_y - fy * fx_y) / den;
            y = y + (fy * fx_x - fx * fy_x) / den;
        }
        // else: nerfstudio takes a zero step (and keeps iterating with the same state).
    }
    (x, y)
}

/// Camera intrinsics in `T` for the pure ray function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics<T> {
    pub model: CameraModel,
    pub fx: T,
    pub fy: T,
    pub cx: T,
    pub cy: T,
    /// `[k1, k2, k3, k4, p1, p2]`.
    pub dist: [T; 6],
    pub distorted: bool,
}

impl Camera {
    /// The intrinsics in `T` (f32 for the GPU twin, f64 for reference).
    pub fn intrinsics<T: Real>(&self) -> Intrinsics<T> {
        Intrinsics {
            model: self.model,
            fx: T::from_f64(self.fx),
            fy: T::from_f64(self.fy),
            cx: T::from_f64(self.cx),
            cy: T::from_f64(self.cy),
            dist: self.distortion.params(),
            distorted: !matches!(self.model, CameraModel::Pinhole | CameraModel::Orthographic)
                && !self.distortion.is_zero(),
        }
    }

    /// World ray through the centre of pixel (row, col) in f64; `c2w` is the 3x4 (or 4x4) camera-to-world.
    pub fn ray_f64(&self, c2w: &[[f64; 4]; 4], row: u32, col: u32) -> Ray<f64> {
        let m = [c2w[0], c2w[1], c2w[2]];
        generate_ray(&self.intrinsics::<f64>(), &m, row as f64 + 0.5, col as f64 + 0.5)
    }

    /// World ray through the centre of pixel (row, col) in f32.
    pub fn ray_f32(&self, c2w: &[[f32; 4]; 3], row: u32, col: u32) -> Ray<f32> {
        generate_ray(&self.intrinsics::<f32>(), c2w, row as f32 + 0.5, col as f32 + 0.5)
    }
}

/// Camera-space direction (OpenGL axes, not normalised) for image point (u, v) in pixels.
#[inline]
pub fn camera_direction<T: Real>(k: &Intrinsics<T>, v: T, u: T) -> [T; 3] {
    let mut x = (u - k.cx) / k.fx;
    let mut y = (v - k.cy) / k.fy;
    if k.distorted {
        let (ux, uy) = undistort(x, y, &k.dist);
        x = ux;
        y = uy;
    }
    let y = -y;
    match k.model {
        CameraModel::OpenCvFisheye => {
            let pi = T::from_f64(std::f64::consts::PI);
            let mut theta = (x * x + y * y).sqrt();
            if theta > pi {
                theta = pi;
            }
            let s = if theta > T::from_f64(1e-12) { theta.sin() / theta } else { T::from_f64(1.0) };
            [x * s, y * s, -theta.cos()]
        }
        _ => [x, y, T::from_f64(-1.0)],
    }
}

/// Pixel (row, col) of camera `cam` (centre `origin`, camera-to-world rotation rows `rot`, OpenGL axes: x right,
/// y up, looking along -z) that sees point `p`, and the distance to it; None behind the camera or outside the image.
/// The inverse of [`camera_direction`]: pinhole and OPENCV (forward [`distort`] of the normalised point),
/// OPENCV_FISHEYE (equidistant: theta = angle from the axis, then the distortion).
pub fn project_point(cam: &Camera, origin: [f64; 3], rot: &[[f64; 3]; 3], p: [f64; 3]) -> Option<(u32, u32, f64)> {
    let (u, v, dist) = project_point_subpixel(cam, origin, rot, p)?;
    Some((v as u32, u as u32, dist))
}

/// [`project_point`] before the pixel is chosen: the sub-pixel image position (u = column, v = row coordinate, pixel
/// centres at +0.5) and the distance; None behind the camera or outside the image.
pub fn project_point_subpixel(
    cam: &Camera,
    origin: [f64; 3],
    rot: &[[f64; 3]; 3],
    p: [f64; 3],
) -> Option<(f64, f64, f64)> {
    use glam::{DMat3, DVec3};
    let d = DVec3::from(p) - DVec3::from(origin);
    // Camera-frame coordinates R^T d: read as columns, the rotation's rows give R^T.
    let xc = DMat3::from_cols_array_2d(rot) * d;
    if cam.model == CameraModel::Orthographic {
        // Parallel projection: the image position is the offset in the camera plane, the distance the depth.
        let (u, v) = (cam.cx + cam.fx * xc.x, cam.cy - cam.fy * xc.y);
        let inside = u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64;
        return (xc.z < 0.0 && inside).then_some((u, v, -xc.z));
    }
    let (mut x, mut y) = if cam.model == CameraModel::OpenCvFisheye {
        let r = xc.truncate().length();
        let theta = r.atan2(-xc.z);
        if r < 1e-12 {
            (0.0, 0.0)
        } else {
            (theta * xc.x / r, -theta * xc.y / r)
        }
    } else {
        if xc.z >= -1e-9 {
            return None;
        }
        (xc.x / -xc.z, -xc.y / -xc.z)
    };
    if cam.model != CameraModel::Pinhole && !cam.distortion.is_zero() {
        (x, y) = distort(x, y, &cam.distortion.params());
    }
    let (u, v) = (cam.cx + cam.fx * x, cam.cy + cam.fy * y);
    if !(u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64) {
        return None;
    }
    Some((u, v, d.length()))
}

/// The pure ray function: image point (v = row coordinate, u = column coordinate, both in pixels, centres at
/// +0.5) to a world ray with camera-to-world `c2w` (3x4, rows).
#[inline]
pub fn generate_ray<T: Real>(k: &Intrinsics<T>, c2w: &[[T; 4]; 3], v: T, u: T) -> Ray<T> {
    let rotate = |d: [T; 3]| [0, 1, 2].map(|i| c2w[i][0] * d[0] + c2w[i][1] * d[1] + c2w[i][2] * d[2]);
    let mut origin = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let zero = T::from_f64(0.0);
    let w = if k.model == CameraModel::Orthographic {
        // The pixel's offset in the camera plane moves the origin; every ray looks along -z.
        let off = rotate([(u - k.cx) / k.fx, -((v - k.cy) / k.fy), zero]);
        origin = [0, 1, 2].map(|i| origin[i] + off[i]);
        rotate([zero, zero, T::from_f64(-1.0)])
    } else {
        rotate(camera_direction(k, v, u))
    };
    let n = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    Ray { origin, direction: [w[0] / n, w[1] / n, w[2] / n], direction_norm: n }
}
