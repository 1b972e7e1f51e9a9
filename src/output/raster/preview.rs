//! 8-bit PNG previews: band composites (natural colour 660/555/450, CIR 840/660/555, any three wavelengths),
//! colour-mapped single planes (vegetation index with a colour bar strip, depth, accumulation, error against
//! ground truth).
//!
//! Stretch per band ([`Stretch`]): a 2–98 % percentile stretch (numpy's linear-interpolation percentile over the
//! finite values), fixed reflectance ranges (0–0.5 for bands centred below 700 nm, 0–0.8 from 700 nm up, i.e. red
//! edge and NIR; 0–1 when the centre is unknown) so that products compare across flights, or a fixed range.
//! NaN pixels are black.

use std::path::Path;

use image::ImageEncoder;

use super::colormap::Colormap;
use crate::output::image::nearest_band;
use crate::output::{atomic, Band, OutputError, Result, SpectralImage};

/// Tolerance for picking composite bands by centre wavelength.
pub const COMPOSITE_TOLERANCE_NM: f64 = 30.0;
pub const NATURAL_COLOUR_NM: [f64; 3] = [660.0, 555.0, 450.0];
pub const CIR_NM: [f64; 3] = [840.0, 660.0, 555.0];

/// An 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rgb8 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl Rgb8 {
    pub fn filled(width: usize, height: usize, colour: [u8; 3]) -> Rgb8 {
        Rgb8 { width, height, data: colour.iter().copied().cycle().take(width * height * 3).collect() }
    }

    pub fn get(&self, x: usize, y: usize) -> [u8; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    pub fn put(&mut self, x: usize, y: usize, c: [u8; 3]) {
        let i = (y * self.width + x) * 3;
        self.data[i..i + 3].copy_from_slice(&c);
    }

    /// PNG bytes.
    pub fn to_png(&self) -> Result<Vec<u8>> {
        let mut buf = Vec::new();
        image::codecs::png::PngEncoder::new(&mut buf)
            .write_image(&self.data, self.width as u32, self.height as u32, image::ExtendedColorType::Rgb8)
            .map_err(|e| OutputError::invalid("png", e))?;
        Ok(buf)
    }

    /// Writes a PNG atomically.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let bytes = self.to_png().map_err(|e| OutputError::write(path, e))?;
        Ok(atomic::write_bytes(path, &bytes)?)
    }
}

/// How band values become display bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stretch {
    /// Per-band percentiles (e.g. 2 and 98).
    Percentile { low: f64, high: f64 },
    /// 0–0.5 below 700 nm, 0–0.8 from 700 nm, 0–1 for bands without a centre.
    Reflectance,
    /// The same range for every band.
    Fixed { min: f64, max: f64 },
}

impl Default for Stretch {
    fn default() -> Self {
        Stretch::Percentile { low: 2.0, high: 98.0 }
    }
}

/// numpy's `percentile(values[isfinite], p)` with linear interpolation (NaN when nothing is finite).
pub fn percentile(values: &[f32], p: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().filter(|x| x.is_finite()).map(|&x| x as f64).collect();
    percentile_of(&mut v, p)
}

fn percentile_of(v: &mut [f64], p: f64) -> f64 {
    v.sort_unstable_by(f64::total_cmp);
    crate::util::stats::quantile_of_sorted(v, p / 100.0)
}

/// The display range of one band under `stretch`.
pub fn band_range(values: &[f32], band: &Band, stretch: Stretch) -> (f64, f64) {
    match stretch {
        Stretch::Percentile { low, high } => {
            let mut v: Vec<f64> = values.iter().filter(|x| x.is_finite()).map(|&x| x as f64).collect();
            (percentile_of(&mut v, low), percentile_of(&mut v, high))
        }
        Stretch::Reflectance => match band.center_nm {
            Some(c) if c < 700.0 => (0.0, 0.5),
            Some(_) => (0.0, 0.8),
            None => (0.0, 1.0),
        },
        Stretch::Fixed { min, max } => (min, max),
    }
}

fn scale_byte(v: f32, lo: f64, hi: f64) -> u8 {
    if !v.is_finite() {
        return 0;
    }
    let t = if hi > lo { (v as f64 - lo) / (hi - lo) } else { 0.5 };
    (t.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Bands `idx` (as R, G, B) of `img`, each stretched on its own.
pub fn composite(img: &SpectralImage, idx: [usize; 3], stretch: Stretch) -> Result<Rgb8> {
    img.validate()?;
    if let Some(&b) = idx.iter().find(|&&b| b >= img.n_bands()) {
        return Err(OutputError::invalid("composite", format!("band {b} of a {}-band image", img.n_bands())));
    }
    let mut out = Rgb8::filled(img.width, img.height, [0; 3]);
    for (c, &b) in idx.iter().enumerate() {
        let data = img.band_data(b);
        let (lo, hi) = band_range(data, &img.bands[b], stretch);
        for (p, &v) in data.iter().enumerate() {
            out.data[p * 3 + c] = scale_byte(v, lo, hi);
        }
    }
    Ok(out)
}

/// The bands nearest to three wavelengths (within [`COMPOSITE_TOLERANCE_NM`]) as R, G, B.
pub fn composite_nm(img: &SpectralImage, nm: [f64; 3], stretch: Stretch, what: &str) -> Result<Rgb8> {
    let mut idx = [0; 3];
    for (i, &w) in nm.iter().enumerate() {
        idx[i] = nearest_band(&img.bands, w, COMPOSITE_TOLERANCE_NM, what)?;
    }
    composite(img, idx, stretch)
}

/// Natural colour (660, 555, 450 nm). A 3-band image without centre wavelengths is taken as R, G, B in order.
pub fn natural_colour(img: &SpectralImage, stretch: Stretch) -> Result<Rgb8> {
    if img.n_bands() == 3 && img.bands.iter().all(|b| b.center_nm.is_none()) {
        return composite(img, [0, 1, 2], stretch);
    }
    composite_nm(img, NATURAL_COLOUR_NM, stretch, "natural colour composite")
}

/// Colour infrared: R = NIR 840, G = red 660, B = green 555 (vegetation shows red).
pub fn cir(img: &SpectralImage, stretch: Stretch) -> Result<Rgb8> {
    composite_nm(img, CIR_NM, stretch, "CIR composite")
}

fn check_plane(values: &[f32], w: usize, h: usize, what: &str) -> Result<()> {
    if w == 0 || h == 0 || values.len() != w * h {
        return Err(OutputError::invalid(what, format!("{} values for {w}x{h} pixels", values.len())));
    }
    Ok(())
}

/// A single plane through a colour map over `[lo, hi]`.
pub fn colormapped(values: &[f32], w: usize, h: usize, cmap: Colormap, range: (f64, f64)) -> Result<Rgb8> {
    check_plane(values, w, h, "plane")?;
    let (lo, hi) = range;
    let span = if hi > lo { hi - lo } else { 1.0 };
    let data =
        values.iter().flat_map(|&v| if v.is_finite() { cmap.map((v as f64 - lo) / span) } else { [0, 0, 0] }).collect();
    Ok(Rgb8 { width: w, height: h, data })
}

/// `img` with a colour bar strip (low → high, left → right) below a 2-pixel black gap.
pub fn with_colorbar(img: &Rgb8, cmap: Colormap) -> Rgb8 {
    let bar_h = (img.height / 16).max(6);
    let gap = 2;
    let mut out = Rgb8::filled(img.width, img.height + gap + bar_h, [0; 3]);
    out.data[..img.data.len()].copy_from_slice(&img.data);
    for x in 0..img.width {
        let t = if img.width > 1 { x as f64 / (img.width - 1) as f64 } else { 0.5 };
        let c = cmap.map(t);
        for y in img.height + gap..out.height {
            out.put(x, y, c);
        }
    }
    out
}

/// A vegetation index plane in RdYlGn over `range` (e.g. (−1, 1) for NDVI) with its colour bar.
pub fn index_preview(values: &[f32], w: usize, h: usize, range: (f64, f64)) -> Result<Rgb8> {
    Ok(with_colorbar(&colormapped(values, w, h, Colormap::RdYlGn, range)?, Colormap::RdYlGn))
}

/// Finite min and max (NaN, NaN when none).
pub fn finite_range(values: &[f32]) -> (f64, f64) {
    values.iter().filter(|v| v.is_finite()).fold((f64::NAN, f64::NAN), |(lo, hi), &v| {
        let v = v as f64;
        (if lo.is_nan() || v < lo { v } else { lo }, if hi.is_nan() || v > hi { v } else { hi })
    })
}

/// Depth through `cmap` (turbo in nerfstudio) over `range`, or the finite min–max when `None`.
pub fn depth_preview(depth: &[f32], w: usize, h: usize, range: Option<(f64, f64)>, cmap: Colormap) -> Result<Rgb8> {
    let r = range.unwrap_or_else(|| finite_range(depth));
    colormapped(depth, w, h, cmap, r)
}

/// Accumulation (opacity) as grey over [0, 1].
pub fn accumulation_preview(acc: &[f32], w: usize, h: usize) -> Result<Rgb8> {
    colormapped(acc, w, h, Colormap::Gray, (0.0, 1.0))
}

/// Per-pixel RMS error over bands of `pred` against `gt`, in inferno over `[0, vmax]` (`vmax` defaults to the
/// largest error). Returns the preview and the `vmax` used.
pub fn error_preview(pred: &SpectralImage, gt: &SpectralImage, vmax: Option<f64>) -> Result<(Rgb8, f64)> {
    gt.check_same_shape(pred, "pred")?;
    let n = gt.n_pixels();
    let nb = gt.n_bands() as f64;
    let err: Vec<f32> = (0..n)
        .map(|p| {
            let s: f64 = (0..gt.n_bands())
                .map(|b| {
                    let d = pred.band_data(b)[p] as f64 - gt.band_data(b)[p] as f64;
                    d * d
                })
                .sum();
            (s / nb).sqrt() as f32
        })
        .collect();
    let vmax = vmax.unwrap_or_else(|| finite_range(&err).1);
    let vmax = if vmax.is_finite() && vmax > 0.0 { vmax } else { 1.0 };
    Ok((colormapped(&err, gt.width, gt.height, Colormap::Inferno, (0.0, vmax))?, vmax))
}
