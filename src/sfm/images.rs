//! The images COLMAP sees: one 8-bit greyscale PNG per frame, `<workspace>/images/<frame stem>.png` (the stem is
//! how `import poses` matches COLMAP's images back to frames).
//!
//! - **Band** (`--band`): a named band (or its index), `pan` (the mean of every band, each stretched first), or
//!   `auto`: the band with the most texture, scored as the mean absolute gradient of the stretched band over up to
//!   four frames spread through the dataset (vegetation is flat in the blue and busy in the NIR and red edge; a
//!   roof the other way round, so no band is right for every scene).
//! - **Stretch**: each image from its own 0.5th to 99.5th percentile to 0-255 (SIFT normalises contrast per
//!   feature; a shared stretch would only waste the 8 bits on dark or bright frames).
//! - **Upsampling** by an integer factor (Catmull-Rom): COLMAP's SIFT starts at the image's own scale (or one
//!   octave up), so small aerial views (64-320 px) give too few features to initialise; `auto` picks the smallest
//!   factor that brings the longer side to 512 px or more, at most 4. COLMAP's intrinsics are divided back by it.

use std::path::{Path, PathBuf};

use super::SfmError;
use crate::data::reader::read_image_file;

/// Which band COLMAP sees.
#[derive(Debug, Clone, PartialEq)]
pub enum BandChoice {
    Auto,
    Pan,
    /// A band name (case-insensitive) or index.
    Named(String),
}

impl BandChoice {
    pub fn parse(s: &str) -> BandChoice {
        match s.to_ascii_lowercase().as_str() {
            "auto" => BandChoice::Auto,
            "pan" | "panchromatic" => BandChoice::Pan,
            _ => BandChoice::Named(s.to_string()),
        }
    }
}

/// Where a frame's pixels are: one multi-band file, or one file per band.
#[derive(Debug, Clone)]
pub struct FrameImages {
    /// The frame's `file_path` (or first band file), as written.
    pub name: String,
    pub files: Vec<PathBuf>,
}

/// One frame's planes (band-major f32), decoded.
struct Planes {
    width: usize,
    height: usize,
    bands: Vec<Vec<f32>>,
}

const MAX_DECODE_BYTES: usize = 4 << 30;

fn decode(f: &FrameImages) -> Result<Planes, SfmError> {
    let mut bands = Vec::new();
    let mut size = None;
    for p in &f.files {
        let img = read_image_file(p, MAX_DECODE_BYTES)
            .map_err(|e| SfmError::Dataset { path: p.clone(), reason: format!("frame {}: {e}", f.name) })?;
        let r = img.raster;
        let s = (r.width as usize, r.height as usize);
        if size.is_some_and(|z| z != s) {
            return Err(SfmError::Dataset {
                path: p.clone(),
                reason: format!("frame {}: band files differ in size ({s:?} against {:?})", f.name, size.unwrap()),
            });
        }
        size = Some(s);
        for b in 0..r.bands {
            bands.push(r.band_f32(b));
        }
    }
    let (width, height) =
        size.ok_or_else(|| SfmError::Dataset { path: f.name.clone().into(), reason: "no image file".into() })?;
    Ok(Planes { width, height, bands })
}

/// A plane stretched from its 0.5th to 99.5th percentile to [0, 1] (non-finite values to 0).
fn stretch(v: &[f32]) -> Vec<f32> {
    let mut s: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return vec![0.0; v.len()];
    }
    s.sort_by(f32::total_cmp);
    let lo = s[s.len() / 200];
    let hi = s[s.len() - 1 - s.len() / 200].max(lo + f32::EPSILON);
    v.iter().map(|x| if x.is_finite() { ((x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 }).collect()
}

/// Mean absolute gradient (x and y differences) of a stretched plane.
fn texture(v: &[f32], w: usize, h: usize) -> f64 {
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for y in 0..h.saturating_sub(1) {
        for x in 0..w.saturating_sub(1) {
            let c = v[y * w + x];
            sum += f64::from((v[y * w + x + 1] - c).abs() + (v[(y + 1) * w + x] - c).abs());
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// The band index `choice` names among `names` (None for `pan`), scoring texture on a few frames for `auto`.
pub fn choose_band(frames: &[FrameImages], names: &[String], choice: &BandChoice) -> Result<Option<usize>, SfmError> {
    match choice {
        BandChoice::Pan => Ok(None),
        BandChoice::Named(n) => {
            if let Some(i) = names.iter().position(|b| b.eq_ignore_ascii_case(n)) {
                return Ok(Some(i));
            }
            match n.parse::<usize>() {
                Ok(i) if i < names.len() => Ok(Some(i)),
                _ => Err(SfmError::Option {
                    key: "--band".into(),
                    reason: format!(
                        "`{n}` is not a band of the dataset ({}), an index, `auto` or `pan`",
                        names.join(", ")
                    ),
                }),
            }
        }
        BandChoice::Auto => {
            let k = frames.len().min(4);
            let mut score = vec![0.0; names.len()];
            for j in 0..k {
                let f = &frames[j * frames.len() / k];
                let p = decode(f)?;
                for (b, s) in score.iter_mut().enumerate().take(p.bands.len()) {
                    *s += texture(&stretch(&p.bands[b]), p.width, p.height);
                }
            }
            Ok(score.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).map(|(i, _)| i))
        }
    }
}

/// The upsampling factor for `auto`: the smallest integer bringing the longer side to 512 px, at most 4.
pub fn auto_upsample(width: u64, height: u64) -> u32 {
    let long = width.max(height).max(1);
    (512u64.div_ceil(long) as u32).clamp(1, 4)
}

/// Writes `dir/<stem>.png` for every frame (band `band`, or the panchromatic mean for None), upsampled by `factor`.
pub fn write_images(
    frames: &[FrameImages],
    stems: &[String],
    band: Option<usize>,
    factor: u32,
    dir: &Path,
) -> Result<(), SfmError> {
    std::fs::create_dir_all(dir).map_err(|e| SfmError::Dataset { path: dir.to_path_buf(), reason: e.to_string() })?;
    for (f, stem) in frames.iter().zip(stems) {
        let p = decode(f)?;
        let plane: Vec<f32> = match band {
            Some(b) => {
                let v = p.bands.get(b).ok_or_else(|| SfmError::Dataset {
                    path: f.files[0].clone(),
                    reason: format!("frame {} has {} bands, band {b} asked for", f.name, p.bands.len()),
                })?;
                stretch(v)
            }
            None => {
                let stretched: Vec<Vec<f32>> = p.bands.iter().map(|v| stretch(v)).collect();
                (0..p.width * p.height)
                    .map(|i| stretched.iter().map(|s| s[i]).sum::<f32>() / stretched.len() as f32)
                    .collect()
            }
        };
        let bytes: Vec<u8> = plane.iter().map(|x| (x * 255.0).round() as u8).collect();
        let mut img = image::GrayImage::from_raw(p.width as u32, p.height as u32, bytes).expect("size matches");
        if factor > 1 {
            img = image::imageops::resize(
                &img,
                p.width as u32 * factor,
                p.height as u32 * factor,
                image::imageops::FilterType::CatmullRom,
            );
        }
        let path = dir.join(format!("{stem}.png"));
        img.save_with_format(&path, image::ImageFormat::Png)
            .map_err(|e| SfmError::Dataset { path: path.clone(), reason: e.to_string() })?;
    }
    Ok(())
}

/// Bands in a frame's files (decodes it).
pub fn band_count(f: &FrameImages) -> Result<usize, SfmError> {
    Ok(decode(f)?.bands.len())
}

/// Width and height of a frame's images (decodes it).
pub fn size_of(f: &FrameImages) -> Result<(u64, u64), SfmError> {
    let p = decode(f)?;
    Ok((p.width as u64, p.height as u64))
}
