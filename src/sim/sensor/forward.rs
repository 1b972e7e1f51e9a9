//! The sensor's forward model: where a raw band pixel looks (lens and rig), and the digital number a radiance
//! becomes (radiometric response, vignetting, row gradient, exposure, gain, shot and read noise, quantisation).
//!
//! MicaSense's published model (micasense/imageprocessing `image.py`, ODM `multispectral.py`) reads
//!
//! ```text
//! L = V(x, y) · R(y) · (p − B) / (g · t_e) · a1 / 2^16,   V = 1 / (1 + k0 r + ... + k5 r^6),
//! R(y) = 1 / (1 + a2 · y / t_e − a3 · y)
//! ```
//!
//! so a radiance L becomes `p = B + L · g · t_e · 2^16 / (a1 · V · R)`. DJI's polynomial multiplies
//! (`V = 1 + k0 r + ...`), there is no a1..a3, and `SensorGainAdjustment` multiplies; the importer then reads a
//! relative radiance that the sun sensor's `Irradiance` (same units) turns into reflectance, so the simulator
//! writes `p = B + L_rel · g · t_e · 2^16 / (V · SGA)` with `L_rel = ρ · Irradiance / π`.
//!
//! Noise, in ADC counts (12-bit for MicaSense, stored shifted left by 4): Gaussian with variance
//! `read^2 + signal / e_per_dn` (read noise and photon shot noise), then rounded and clamped to the ADC range.

use super::profile::{BandCamera, SensorProfile, Vendor};
use crate::rig::calib::Lens;
use crate::sim::effects::normal;

/// Inverts OpenCV's Brown-Conrady distortion for normalised distorted coordinates (fixed-point iteration, as
/// `cv::undistortPoints`, run to 1e-12 of normalised error).
pub fn undistort(l: &Lens, xd: f64, yd: f64) -> (f64, f64) {
    let (mut x, mut y) = (xd, yd);
    for _ in 0..50 {
        let (dx, dy) = crate::rig::lens::distort(l, x, y);
        let (ex, ey) = (dx - xd, dy - yd);
        x -= ex;
        y -= ey;
        if ex.abs() < 1e-12 && ey.abs() < 1e-12 {
            break;
        }
    }
    (x, y)
}

/// Rotation of MicaSense's `RigRelatives` (degrees): R = Rx Ry Rz (micasense `rotations_degrees_to_rotation_matrix`).
pub fn rig_rotation(deg: [f64; 3]) -> glam::DMat3 {
    let [a, b, c] = deg.map(f64::to_radians);
    glam::DMat3::from_rotation_x(a) * glam::DMat3::from_rotation_y(b) * glam::DMat3::from_rotation_z(c)
}

/// A band camera of the rig relative to the reference camera (OpenCV axes: x right, y down, z forward):
/// `ref_from_band` rotates the band's rays into the reference camera, `center` is the band camera's centre.
#[derive(Debug, Clone, Copy)]
pub struct RigPose {
    pub ref_from_band: glam::DMat3,
    pub center: glam::DVec3,
}

impl RigPose {
    pub fn of(profile: &SensorProfile, b: &BandCamera) -> RigPose {
        let r_ref = rig_rotation(profile.bands[profile.reference].rig_rotation_deg);
        let t_ref = glam::DVec3::from(profile.bands[profile.reference].rig_translation_m);
        RigPose {
            ref_from_band: r_ref.transpose() * rig_rotation(b.rig_rotation_deg),
            center: glam::DVec3::from(b.rig_translation_m) - t_ref,
        }
    }
}

/// The ray of raw pixel (u, v) (pixel centres at integers) of a band camera, in the world frame of the
/// reference camera's OpenGL camera-to-world `c2w`: (origin, unit direction).
pub fn band_ray(l: &Lens, rig: &RigPose, c2w: &[[f64; 4]; 4], u: f64, v: f64) -> ([f64; 3], [f64; 3]) {
    let (x, y) = undistort(l, (u - l.cx) / l.fx, (v - l.cy) / l.fy);
    let d_ref = rig.ref_from_band * glam::DVec3::new(x, y, 1.0);
    // OpenCV -> OpenGL camera axes.
    let gl = |p: glam::DVec3| [p.x, -p.y, -p.z];
    let (d, o) = (gl(d_ref), gl(rig.center));
    let rot = |p: [f64; 3]| [0, 1, 2].map(|i| c2w[i][0] * p[0] + c2w[i][1] * p[1] + c2w[i][2] * p[2]);
    let (dw, ow) = (rot(d), rot(o));
    let n = (dw[0] * dw[0] + dw[1] * dw[1] + dw[2] * dw[2]).sqrt();
    ([c2w[0][3] + ow[0], c2w[1][3] + ow[1], c2w[2][3] + ow[2]], dw.map(|c| c / n))
}

/// Where a point (world frame) lands in a band's raw image, or `None` behind the camera.
pub fn project(l: &Lens, rig: &RigPose, c2w: &[[f64; 4]; 4], p: [f64; 3]) -> Option<(f64, f64)> {
    // World -> reference camera (OpenGL) -> OpenCV -> band camera.
    let c = [p[0] - c2w[0][3], p[1] - c2w[1][3], p[2] - c2w[2][3]];
    let cam_gl = [0, 1, 2].map(|j| (0..3).map(|i| c2w[i][j] * c[i]).sum::<f64>());
    let cam_cv = glam::DVec3::new(cam_gl[0], -cam_gl[1], -cam_gl[2]);
    let b = rig.ref_from_band.transpose() * (cam_cv - rig.center);
    if b.z <= 0.0 {
        return None;
    }
    let (x, y) = (b.x / b.z, b.y / b.z);
    if !within_lens(l, x * x + y * y) {
        return None;
    }
    let (xd, yd) = crate::rig::lens::distort(l, x, y);
    Some((l.fx * xd + l.cx, l.fy * yd + l.cy))
}

/// Whether the lens's radial polynomial is still increasing out to the normalised radius sqrt(`r2`): beyond its
/// first turning point Brown's model folds far-off directions back into the frame (a point kilometres outside the
/// field of view would land in the image).
fn within_lens(l: &Lens, r2: f64) -> bool {
    const STEPS: usize = 64;
    (1..=STEPS).all(|i| {
        let s = r2 * i as f64 / STEPS as f64;
        1.0 + s * (3.0 * l.k1 + s * (5.0 * l.k2 + s * 7.0 * l.k3)) > 0.0
    })
}

/// The vignetting polynomial `1 + k0 r + ... + k5 r^6` at raw pixel (x, y).
pub fn vignetting_poly(b: &BandCamera, x: f64, y: f64) -> f64 {
    let r = (x - b.vignetting_center[0]).hypot(y - b.vignetting_center[1]);
    let mut p = 0.0;
    for k in b.vignetting_poly.iter().rev() {
        p = p * r + k;
    }
    1.0 + p * r
}

/// Noise-free container DN (fractional) of radiance `l` at raw pixel (x, y) for an exposure and gain.
pub fn radiance_to_dn(p: &SensorProfile, b: &BandCamera, l: f64, x: f64, y: f64, exposure_s: f64, gain: f64) -> f64 {
    let full = 65536.0;
    match p.vendor {
        Vendor::MicaSense => {
            let [a1, a2, a3] = b.radiometric;
            let inv_row = 1.0 + a2 * y / exposure_s - a3 * y;
            p.black_level + l * gain * exposure_s * full * vignetting_poly(b, x, y) * inv_row / a1
        }
        Vendor::Dji => p.black_level + l * gain * exposure_s * full / (vignetting_poly(b, x, y) * b.gain_adjustment),
    }
}

/// Adds read and shot noise to a container DN and quantises it to the ADC (stored shifted). `key` is a
/// (capture, band, pixel) counter for the seeded normal variate.
pub fn quantise(p: &SensorProfile, dn: f64, seed: u64, stream: u64, key: u64) -> u16 {
    let step = (1u64 << p.adc_shift) as f64;
    let top = ((1u64 << p.adc_bits) - 1) as f64;
    let adc = dn / step;
    let signal = (dn - p.black_level).max(0.0) / step;
    let var = p.read_noise_dn * p.read_noise_dn + signal / p.electrons_per_dn;
    let noisy = adc + var.sqrt() * normal(seed, stream, key, 0);
    (noisy.round().clamp(0.0, top) * step) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A direction far outside the field of view, where Brown's polynomial folds back to the image centre, does not
    /// project (a ground control point there would be a click in an image that never saw it).
    #[test]
    fn far_off_directions_do_not_fold_into_the_frame() {
        let l = Lens { fx: 1000.0, fy: 1000.0, cx: 640.0, cy: 480.0, k1: -0.2, k2: 0.0, k3: 0.0, p1: 0.0, p2: 0.0 };
        let rig = RigPose { ref_from_band: glam::DMat3::IDENTITY, center: glam::DVec3::ZERO };
        // A nadir reference camera at 40 m (OpenGL: looking along -z).
        let c2w = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 40.0], [0.0, 0.0, 0.0, 1.0]];
        let (u, v) = project(&l, &rig, &c2w, [4.0, 0.0, 0.0]).expect("in view");
        assert!((u - (640.0 + 1000.0 * 0.1 * (1.0 - 0.2 * 0.01))).abs() < 1e-9 && (v - 480.0).abs() < 1e-9);
        // x / z = sqrt(5): r (1 + k1 r^2) = 0, the principal point.
        let far = [40.0 * 5f64.sqrt(), 0.0, 0.0];
        let (xd, _) = crate::rig::lens::distort(&l, 5f64.sqrt(), 0.0);
        assert!(xd.abs() < 1e-12, "the polynomial folds back: {xd}");
        assert_eq!(project(&l, &rig, &c2w, far), None);
    }
}
