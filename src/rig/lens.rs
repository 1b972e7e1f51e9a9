//! Lens geometry: OpenCV's Brown-Conrady model (k1, k2, k3 radial, p1, p2 tangential; pixel centres at integer
//! coordinates) and the one resampling that undistorts and registers a band in a single interpolation.
//!
//! Every band is resampled into one *target* pinhole camera (the reference band's focal length and principal
//! point, no distortion). A target pixel u goes to the band's raw pixel as
//! `K_band * distort_band(K_target^-1 * W(u))`, W being the band's registration warp in target pixels
//! (identity for the reference band); see [`super::register`] and [`super::warp`].

use super::calib::Lens;
use super::plane::Plane;
use super::warp::Warp;

/// Applies the distortion to normalised coordinates.
#[inline]
pub fn distort(l: &Lens, x: f64, y: f64) -> (f64, f64) {
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (l.k1 + r2 * (l.k2 + r2 * l.k3));
    let xd = x * radial + 2.0 * l.p1 * x * y + l.p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + l.p1 * (r2 + 2.0 * y * y) + 2.0 * l.p2 * x * y;
    (xd, yd)
}

/// The undistorted pinhole camera everything is resampled into.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Target {
    pub width: usize,
    pub height: usize,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Where target pixel (x, y) samples the band's raw image.
#[inline]
pub fn source_pixel(target: &Target, lens: Option<&Lens>, warp: &Warp, x: f64, y: f64) -> (f64, f64) {
    let (u, v) = warp.apply(x, y);
    match lens {
        None => (u, v),
        Some(l) => {
            let (xn, yn) = ((u - target.cx) / target.f, (v - target.cy) / target.f);
            let (xd, yd) = distort(l, xn, yn);
            (l.fx * xd + l.cx, l.fy * yd + l.cy)
        }
    }
}

/// Resamples `src` into the target camera through `h` (bicubic, [`Plane::sample_cubic`]; NaN where the source has
/// no pixel).
pub fn resample(src: &Plane, target: &Target, lens: Option<&Lens>, warp: &Warp) -> Plane {
    let mut out = vec![f32::NAN; target.width * target.height];
    for y in 0..target.height {
        for x in 0..target.width {
            let (sx, sy) = source_pixel(target, lens, warp, x as f64, y as f64);
            if let Some(v) = src.sample_cubic(sx, sy) {
                out[y * target.width + x] = v;
            }
        }
    }
    Plane::new(target.width, target.height, out)
}
