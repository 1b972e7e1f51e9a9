//! `Raster`: one image held compactly in its source sample type (u8/u16/u32/f16/f32), pixel-interleaved,
//! with per-band scaling applied only when values are read as f32.
//!
//! Integers are mapped to `(raw − black_level) / scale` where `scale` is `pixel_scale` when the dataset
//! gives it and 2^bits − 1 of the stored type otherwise; floats are returned as stored (no clamping).
//! There is no 8-bit step anywhere: a u16 stays a u16 until it is turned into an f32.

use half::f16;
use serde::Serialize;

/// The type samples are stored in, in the file and in memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SampleType {
    U8,
    U16,
    U32,
    F16,
    F32,
}

impl SampleType {
    /// Bytes per sample in memory.
    pub fn bytes(self) -> usize {
        match self {
            SampleType::U8 => 1,
            SampleType::U16 | SampleType::F16 => 2,
            SampleType::U32 | SampleType::F32 => 4,
        }
    }

    /// 2^bits − 1 for integer types (the default divisor), 1 for floats.
    pub fn default_scale(self) -> f64 {
        match self {
            SampleType::U8 => 255.0,
            SampleType::U16 => 65535.0,
            SampleType::U32 => 4294967295.0,
            SampleType::F16 | SampleType::F32 => 1.0,
        }
    }

    /// Whether the type holds integers (scaled and black-level corrected on access).
    pub fn is_integer(self) -> bool {
        matches!(self, SampleType::U8 | SampleType::U16 | SampleType::U32)
    }
}

/// Samples of one image, pixel-interleaved: index `(row * width + col) * bands + band`.
#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
    U32(Vec<u32>),
    F16(Vec<f16>),
    F32(Vec<f32>),
}

impl Samples {
    /// Zeroed storage of `len` samples of type `ty`.
    pub fn zeros(ty: SampleType, len: usize) -> Samples {
        match ty {
            SampleType::U8 => Samples::U8(vec![0; len]),
            SampleType::U16 => Samples::U16(vec![0; len]),
            SampleType::U32 => Samples::U32(vec![0; len]),
            SampleType::F16 => Samples::F16(vec![f16::ZERO; len]),
            SampleType::F32 => Samples::F32(vec![0.0; len]),
        }
    }

    pub fn sample_type(&self) -> SampleType {
        match self {
            Samples::U8(_) => SampleType::U8,
            Samples::U16(_) => SampleType::U16,
            Samples::U32(_) => SampleType::U32,
            Samples::F16(_) => SampleType::F16,
            Samples::F32(_) => SampleType::F32,
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Samples::U8(v) => v.len(),
            Samples::U16(v) => v.len(),
            Samples::U32(v) => v.len(),
            Samples::F16(v) => v.len(),
            Samples::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The raw stored value at `i` as f64 (exact for every type).
    #[inline]
    pub fn raw(&self, i: usize) -> f64 {
        match self {
            Samples::U8(v) => v[i] as f64,
            Samples::U16(v) => v[i] as f64,
            Samples::U32(v) => v[i] as f64,
            Samples::F16(v) => v[i].to_f64(),
            Samples::F32(v) => v[i] as f64,
        }
    }

    /// Copies sample `src_i` of `src` (same type) into `self[dst_i]`. Returns false on a type mismatch.
    #[inline]
    pub fn copy_from(&mut self, dst_i: usize, src: &Samples, src_i: usize) -> bool {
        match (self, src) {
            (Samples::U8(d), Samples::U8(s)) => d[dst_i] = s[src_i],
            (Samples::U16(d), Samples::U16(s)) => d[dst_i] = s[src_i],
            (Samples::U32(d), Samples::U32(s)) => d[dst_i] = s[src_i],
            (Samples::F16(d), Samples::F16(s)) => d[dst_i] = s[src_i],
            (Samples::F32(d), Samples::F32(s)) => d[dst_i] = s[src_i],
            _ => return false,
        }
        true
    }

    /// One pass over the float samples of the pixels `mask` keeps (all without a mask; `bands` samples per pixel):
    /// how many are NaN/Inf, how many are finite but beyond ±`limit`, and the one farthest out. Integer samples
    /// are bounded by their scaling (checked there): all zero.
    pub fn value_check(&self, bands: usize, mask: Option<&[u8]>, limit: f32) -> ValueCheck {
        fn scan<T: Copy>(v: &[T], bands: usize, mask: Option<&[u8]>, f: impl Fn(T) -> f32, limit: f32) -> ValueCheck {
            let mut c = ValueCheck::default();
            for (p, px) in v.chunks_exact(bands.max(1)).enumerate() {
                if mask.is_some_and(|m| m[p] == 0) {
                    continue;
                }
                for &x in px {
                    let x = f(x);
                    if !x.is_finite() {
                        c.non_finite += 1;
                    } else if x.abs() > limit {
                        c.beyond += 1;
                        if x.abs() as f64 > c.extreme.abs() {
                            c.extreme = x as f64;
                        }
                    }
                }
            }
            c
        }
        match self {
            // fp16 tops out at 65504: nothing finite lies beyond the limit.
            Samples::F16(v) => scan(v, bands, mask, |x| if x.is_finite() { 0.0 } else { f32::NAN }, limit),
            Samples::F32(v) => scan(v, bands, mask, |x| x, limit),
            _ => ValueCheck::default(),
        }
    }

    /// The largest stored value (integer types; 0 for floats).
    pub fn max_raw(&self) -> f64 {
        match self {
            Samples::U8(v) => v.iter().copied().max().unwrap_or(0) as f64,
            Samples::U16(v) => v.iter().copied().max().unwrap_or(0) as f64,
            Samples::U32(v) => v.iter().copied().max().unwrap_or(0) as f64,
            _ => 0.0,
        }
    }
}

/// What [`Samples::value_check`] found.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ValueCheck {
    pub non_finite: u64,
    pub beyond: u64,
    pub extreme: f64,
}

/// Per-band mapping from stored values to model values: `(raw − black) / scale`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BandScale {
    pub black: f64,
    pub scale: f64,
}

impl BandScale {
    pub const IDENTITY: BandScale = BandScale { black: 0.0, scale: 1.0 };

    /// The model value farthest from 0 that stored values in `0..=max_raw` map to.
    pub fn extreme(&self, max_raw: f64) -> f64 {
        let (lo, hi) = ((0.0 - self.black) / self.scale, (max_raw - self.black) / self.scale);
        if lo.abs() > hi.abs() || lo.is_nan() {
            lo
        } else {
            hi
        }
    }
}

/// Largest plausible |model value| of a pixel. Calibrated reflectance lies near [0, 1] and integer data is scaled
/// into it; values beyond this are a nodata marker (GDAL's float nodata is -3.4e38), a unit mistake or a degenerate
/// `pixel_scale`, and their squares would overflow the loss's float sums.
pub const MAX_MODEL_VALUE: f64 = 1e6;

/// An image's alpha channel and what it is composited over (nerfstudio's `blend_background`): a band's model
/// value v becomes `v·α + bg·(1 − α)` (straight alpha) or `v + bg·(1 − α)` (associated, i.e. premultiplied,
/// alpha), with α the stored alpha over the type's full scale (2^bits − 1 for integers, 1 for floats), clamped
/// to [0, 1]. The colour bands' black level and pixel scale do not apply to α.
#[derive(Debug, Clone, PartialEq)]
pub struct Alpha {
    /// One sample per pixel, row-major, in the file's sample type.
    pub samples: Samples,
    /// Whether the colour is premultiplied by α (TIFF ExtraSamples 1, OpenEXR); straight alpha otherwise (PNG,
    /// TIFF ExtraSamples 2).
    pub associated: bool,
    /// The background's model value, the same in every band.
    pub background: f64,
}

impl Alpha {
    /// α of pixel `p` in [0, 1].
    #[inline]
    pub fn at(&self, p: usize) -> f64 {
        (self.samples.raw(p) / self.samples.sample_type().default_scale()).clamp(0.0, 1.0)
    }

    /// Model value `v` of pixel `p` composited over the background.
    #[inline]
    pub fn blend(&self, p: usize, v: f64) -> f64 {
        let a = self.at(p);
        let colour = if self.associated { v } else { v * a };
        colour + self.background * (1.0 - a)
    }
}

/// One decoded image: `bands` samples per pixel, row 0 at the top, plus an optional validity mask and an
/// optional alpha channel that every value read is composited with.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster {
    pub width: u32,
    pub height: u32,
    pub bands: usize,
    pub samples: Samples,
    /// One entry per band; identity for float images.
    pub scaling: Vec<BandScale>,
    /// Optional per-pixel mask, `width * height` bytes, 0 = ignore the pixel.
    pub mask: Option<Vec<u8>>,
    /// Optional alpha channel (not one of the `bands`), applied by every accessor that returns model values.
    pub alpha: Option<Alpha>,
}

impl Raster {
    /// Builds a raster, checking that the sample count matches the shape.
    pub fn new(width: u32, height: u32, bands: usize, samples: Samples) -> Option<Raster> {
        if samples.len() != width as usize * height as usize * bands || bands == 0 {
            return None;
        }
        Some(Raster {
            width,
            height,
            bands,
            samples,
            scaling: vec![BandScale::IDENTITY; bands],
            mask: None,
            alpha: None,
        })
    }

    pub fn sample_type(&self) -> SampleType {
        self.samples.sample_type()
    }

    /// Bytes held in memory (samples plus mask and alpha).
    pub fn bytes(&self) -> u64 {
        (self.samples.len() * self.sample_type().bytes()) as u64
            + self.mask.as_ref().map_or(0, |m| m.len() as u64)
            + self.alpha.as_ref().map_or(0, |a| (a.samples.len() * a.samples.sample_type().bytes()) as u64)
    }

    /// Model value of band `band` at pixel index `p`: scaled, then composited over the background when the
    /// raster has an alpha channel.
    #[inline]
    fn value(&self, p: usize, band: usize) -> f32 {
        let s = self.scaling[band];
        let v = (self.samples.raw(p * self.bands + band) - s.black) / s.scale;
        match &self.alpha {
            None => v as f32,
            Some(a) => a.blend(p, v) as f32,
        }
    }

    /// Stored value of one sample, unscaled.
    #[inline]
    pub fn raw(&self, row: u32, col: u32, band: usize) -> f64 {
        self.samples.raw((row as usize * self.width as usize + col as usize) * self.bands + band)
    }

    /// Model value of one sample: `(raw − black) / scale` as f32 (composited over the background when the raster
    /// has an alpha channel).
    #[inline]
    pub fn get(&self, row: u32, col: u32, band: usize) -> f32 {
        self.value(row as usize * self.width as usize + col as usize, band)
    }

    /// All bands of one pixel as f32 into `out` (length `bands`).
    #[inline]
    pub fn pixel_into(&self, row: u32, col: u32, out: &mut [f32]) {
        let p = row as usize * self.width as usize + col as usize;
        for (b, o) in out.iter_mut().enumerate().take(self.bands) {
            *o = self.value(p, b);
        }
    }

    /// Mask value of a pixel (1 when there is no mask).
    #[inline]
    pub fn mask_at(&self, row: u32, col: u32) -> u8 {
        match &self.mask {
            Some(m) => m[row as usize * self.width as usize + col as usize],
            None => 1,
        }
    }

    /// One band as f32, row-major (for checks and tests; allocates).
    pub fn band_f32(&self, band: usize) -> Vec<f32> {
        let n = self.width as usize * self.height as usize;
        (0..n).map(|p| self.value(p, band)).collect()
    }

    /// Per-band (min, max) of the model values over the finite samples of the pixels the mask keeps; `None` for a
    /// band with none.
    pub fn band_ranges(&self) -> Vec<Option<(f32, f32)>> {
        let mut r: Vec<Option<(f32, f32)>> = vec![None; self.bands];
        let n = self.width as usize * self.height as usize;
        for p in 0..n {
            // What the mask leaves out (nodata borders) is not data.
            if self.mask.as_ref().is_some_and(|m| m[p] == 0) {
                continue;
            }
            for (b, slot) in r.iter_mut().enumerate() {
                let v = self.value(p, b);
                if v.is_finite() {
                    *slot = Some(match *slot {
                        None => (v, v),
                        Some((lo, hi)) => (lo.min(v), hi.max(v)),
                    });
                }
            }
        }
        r
    }
}
