//! Raw DN -> radiance, MicaSense's published model (docs/radiometry.md; spec/multispectral.md §4.3):
//!
//! `L = V(x, y) * R(y) * (p - B) / (g * t_e) * a1 / 2^bits`, clamped at 0, with the vignetting factor
//! `V = 1 / (1 + k0 r + k1 r^2 + ... + k5 r^6)`, `r` the distance in pixels from `VignettingCenter` to the pixel
//! (x = column, y = row, pixel centres at integers), and the row-gradient correction
//! `R = 1 / (1 + a2 y / t_e - a3 y)`. Units: W / (m^2 sr nm).
//!
//! DJI's variant: the polynomial *multiplies* (`V = 1 + k0 r + ...`), there is no a1/a2/a3 (R = 1, a1 = 1) and
//! `SensorGainAdjustment` multiplies, giving a relative radiance; a generic rig gets the MicaSense form with
//! a1 = 1, a2 = a3 = 0 (relative radiance). Either is made absolute by a calibration panel.

use super::calib::{BandFile, VignettingMode};
use super::plane::Plane;

/// What a radiance conversion found.
#[derive(Debug, Clone, Copy, Default)]
pub struct RadianceStats {
    /// Pixels at the top of the sensor's range (saturated: their radiance is a lower bound).
    pub saturated: usize,
}

/// Radiance units the conversion produces for a band file.
pub fn radiance_units(b: &BandFile) -> &'static str {
    if b.radiometric.is_some() {
        "W/(m^2 sr nm)"
    } else {
        "relative"
    }
}

/// The vignetting factor at pixel (x, y) (what the signal is multiplied by).
#[inline]
pub fn vignetting_factor(b: &BandFile, x: f64, y: f64) -> f64 {
    let Some([cx, cy]) = b.vignetting_center else { return 1.0 };
    if b.vignetting_poly.is_empty() {
        return 1.0;
    }
    let r = (x - cx).hypot(y - cy);
    let mut poly = 0.0;
    for k in b.vignetting_poly.iter().rev() {
        poly = poly * r + k;
    }
    let p = 1.0 + poly * r;
    match b.vignetting_mode {
        VignettingMode::Divide => 1.0 / p,
        VignettingMode::Multiply => p,
    }
}

/// Saturation threshold: the top 0.1 % of the container's range (12-bit data shifted by 4 tops out at 65520).
pub fn saturation_level(b: &BandFile) -> f64 {
    0.999 * ((1u64 << b.meta.bits_per_sample.min(32)) as f64 - 1.0)
}

/// Converts raw DN (row-major, `meta.width` x `meta.height`) to radiance.
pub fn to_radiance(b: &BandFile, raw: &[f64]) -> (Plane, RadianceStats) {
    let (w, h) = (b.meta.width as usize, b.meta.height as usize);
    let [a1, a2, a3] = b.radiometric.unwrap_or([1.0, 0.0, 0.0]);
    let scale = a1 * b.gain_adjustment / (b.gain * b.exposure_s * (1u64 << b.meta.bits_per_sample.min(32)) as f64);
    let sat_level = saturation_level(b);
    let mut out = vec![0.0f32; w * h];
    let mut stats = RadianceStats::default();
    for y in 0..h {
        let yf = y as f64;
        let row = 1.0 / (1.0 + a2 * yf / b.exposure_s - a3 * yf);
        for x in 0..w {
            let p = raw[y * w + x];
            if p >= sat_level {
                stats.saturated += 1;
            }
            let l = vignetting_factor(b, x as f64, yf) * row * (p - b.black_level);
            out[y * w + x] = (l.max(0.0) * scale) as f32;
        }
    }
    (Plane::new(w, h, out), stats)
}
