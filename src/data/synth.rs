//! Writes synthetic rig datasets (one 16-bit single-band TIFF per band, MicaSense layout) for the benchmark
//! and tests, with the `tiff` crate's encoder. Values are a deterministic function of (frame, band, pixel) so
//! readers can be checked bit for bit; poses circle a UTM-sized offset looking down.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use tiff::encoder::{colortype, TiffEncoder};

/// What to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SynthSpec {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub bands: usize,
}

/// The stored value of (frame, band, row, col): a 12-bit DN shifted by 4, like MicaSense.
pub fn synth_value(frame: usize, band: usize, row: u32, col: u32) -> u16 {
    let mut x = (frame as u64) << 40 ^ (band as u64) << 32 ^ (row as u64) << 16 ^ col as u64;
    x = x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x ^= x >> 29;
    ((x & 0x0fff) as u16) << 4
}

/// Writes `dir/transforms.json` and `dir/images/f{frame}_b{band}.tif`.
pub fn write_synthetic_dataset(dir: &Path, spec: &SynthSpec) -> std::io::Result<()> {
    let img = dir.join("images");
    std::fs::create_dir_all(&img)?;
    let names = ["blue", "green", "red", "rededge1", "rededge2", "nir", "b7", "b8", "b9", "b10"];
    let centres = [450.0, 555.0, 660.0, 720.0, 750.0, 840.0, 900.0, 950.0, 1000.0, 1050.0];
    let bands: Vec<serde_json::Value> = (0..spec.bands)
        .map(|b| serde_json::json!({"name": names[b % 10], "center_nm": centres[b % 10], "fwhm_nm": 20.0}))
        .collect();
    let mut frames = Vec::new();
    let mut buf = vec![0u16; (spec.width * spec.height) as usize];
    for f in 0..spec.frames {
        let mut files = Vec::new();
        for b in 0..spec.bands {
            for r in 0..spec.height {
                for c in 0..spec.width {
                    buf[(r * spec.width + c) as usize] = synth_value(f, b, r, c);
                }
            }
            let name = format!("images/f{f:05}_b{b}.tif");
            let out = BufWriter::new(File::create(dir.join(&name))?);
            let mut enc = TiffEncoder::new(out).map_err(std::io::Error::other)?;
            enc.write_image::<colortype::Gray16>(spec.width, spec.height, &buf).map_err(std::io::Error::other)?;
            files.push(name);
        }
        let a = f as f64 / spec.frames.max(1) as f64 * std::f64::consts::TAU;
        // Camera looking straight down (-z) from 100 m above a circle of radius 50 m at a UTM offset.
        let (x, y) = (500_000.0 + 50.0 * a.cos(), 4_000_000.0 + 50.0 * a.sin());
        frames.push(serde_json::json!({
            "band_files": files,
            "transform_matrix": [[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, y], [0.0, 0.0, 1.0, 100.0], [0.0, 0.0, 0.0, 1.0]],
        }));
    }
    let j = serde_json::json!({
        "camera_model": "PINHOLE",
        "fl_x": spec.width as f64, "fl_y": spec.width as f64,
        "cx": spec.width as f64 / 2.0, "cy": spec.height as f64 / 2.0,
        "w": spec.width, "h": spec.height,
        "pixel_scale": 65520,
        "bands": bands,
        "frames": frames,
    });
    std::fs::write(dir.join("transforms.json"), serde_json::to_string_pretty(&j)?)
}
