//! SSIM exactly as scikit-image's `structural_similarity(im1, im2, gaussian_weights=True, sigma=1.5,
//! use_sample_covariance=False, data_range=R)` computes it for float64 input:
//!
//! - window: Gaussian, σ = 1.5, truncated at 3.5σ → radius `int(3.5·1.5 + 0.5)` = 5, 11 taps, normalised to sum 1
//!   (`scipy.ndimage.gaussian_filter`, separable, axis 0 then axis 1, `mode="reflect"`, i.e. `d c b a | a b c d`);
//! - local moments `ux, uy, uxx, uyy, uxy` by that filter; `vx = uxx − ux²`, `vy`, `vxy` (population covariance);
//! - `C1 = (0.01·R)²`, `C2 = (0.03·R)²`; `S = (2·ux·uy + C1)(2·vxy + C2) / ((ux² + uy² + C1)(vx + vy + C2))`;
//! - the map is cropped by `(11 − 1) / 2 = 5` pixels on every side before averaging.
//!
//! Both sides must be at least 11 pixels (skimage raises otherwise). Everything runs in f64.

use crate::output::{OutputError, Result};

pub const SIGMA: f64 = 1.5;
pub const TRUNCATE: f64 = 3.5;
pub const K1: f64 = 0.01;
pub const K2: f64 = 0.03;
/// `int(TRUNCATE·SIGMA + 0.5)`.
pub const RADIUS: usize = 5;
pub const WIN_SIZE: usize = 2 * RADIUS + 1;
/// skimage's `pad = (win_size − 1) // 2`.
pub const CROP: usize = (WIN_SIZE - 1) / 2;

/// scipy's `_gaussian_kernel1d(sigma, 0, radius)`: `exp(−x²/(2σ²))` normalised over `x ∈ [−r, r]`.
pub fn gaussian_kernel() -> [f64; WIN_SIZE] {
    let mut k = [0.0; WIN_SIZE];
    let s2 = SIGMA * SIGMA;
    for (i, w) in k.iter_mut().enumerate() {
        let x = i as f64 - RADIUS as f64;
        *w = (-0.5 / s2 * x * x).exp();
    }
    let sum: f64 = k.iter().sum();
    k.iter_mut().for_each(|w| *w /= sum);
    k
}

/// scipy "reflect" index: `d c b a | a b c d | d c b a`.
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let period = 2 * n;
    let mut j = i.rem_euclid(period);
    if j >= n {
        j = period - 1 - j;
    }
    j as usize
}

/// Separable Gaussian filter of a `w × h` row-major image: along axis 0 (columns, vertical) then axis 1.
pub fn gaussian_filter(img: &[f64], w: usize, h: usize) -> Vec<f64> {
    let k = gaussian_kernel();
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (t, &kw) in k.iter().enumerate() {
                let yy = reflect(y as isize + t as isize - RADIUS as isize, h);
                s += kw * img[yy * w + x];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        let row = &tmp[y * w..(y + 1) * w];
        for x in 0..w {
            let mut s = 0.0;
            for (t, &kw) in k.iter().enumerate() {
                s += kw * row[reflect(x as isize + t as isize - RADIUS as isize, w)];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// The full (uncropped) SSIM map of two single-band `w × h` images.
pub fn ssim_map(a: &[f32], b: &[f32], w: usize, h: usize, data_range: f64) -> Result<Vec<f64>> {
    if a.len() != w * h || b.len() != w * h {
        return Err(OutputError::invalid("ssim", format!("images of {} and {} values for {w}x{h}", a.len(), b.len())));
    }
    if w < WIN_SIZE || h < WIN_SIZE {
        return Err(OutputError::invalid(
            "ssim",
            format!("image {w}x{h} is smaller than the {WIN_SIZE}x{WIN_SIZE} Gaussian window"),
        ));
    }
    if !(data_range > 0.0 && data_range.is_finite()) {
        return Err(OutputError::invalid("data_range", format!("must be positive and finite, got {data_range}")));
    }
    let x: Vec<f64> = a.iter().map(|&v| v as f64).collect();
    let y: Vec<f64> = b.iter().map(|&v| v as f64).collect();
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
    let ux = gaussian_filter(&x, w, h);
    let uy = gaussian_filter(&y, w, h);
    let uxx = gaussian_filter(&xx, w, h);
    let uyy = gaussian_filter(&yy, w, h);
    let uxy = gaussian_filter(&xy, w, h);
    let c1 = (K1 * data_range).powi(2);
    let c2 = (K2 * data_range).powi(2);
    Ok((0..w * h)
        .map(|i| {
            let vx = uxx[i] - ux[i] * ux[i];
            let vy = uyy[i] - uy[i] * uy[i];
            let vxy = uxy[i] - ux[i] * uy[i];
            let a1 = 2.0 * ux[i] * uy[i] + c1;
            let a2 = 2.0 * vxy + c2;
            let b1 = ux[i] * ux[i] + uy[i] * uy[i] + c1;
            let b2 = vx + vy + c2;
            (a1 * a2) / (b1 * b2)
        })
        .collect())
}

/// Mean SSIM over the map cropped by [`CROP`] pixels, restricted to `mask` (true = counted) when given.
/// Returns NaN when the mask leaves no pixel inside the cropped area.
pub fn ssim(a: &[f32], b: &[f32], w: usize, h: usize, mask: Option<&[bool]>, data_range: f64) -> Result<f64> {
    if let Some(m) = mask {
        if m.len() != w * h {
            return Err(OutputError::invalid("mask", format!("{} values for {w}x{h} pixels", m.len())));
        }
    }
    let s = ssim_map(a, b, w, h, data_range)?;
    let mut sum = 0.0;
    let mut n = 0usize;
    for y in CROP..h - CROP {
        for x in CROP..w - CROP {
            let i = y * w + x;
            if mask.is_none_or(|m| m[i]) {
                sum += s[i];
                n += 1;
            }
        }
    }
    Ok(if n == 0 { f64::NAN } else { sum / n as f64 })
}
