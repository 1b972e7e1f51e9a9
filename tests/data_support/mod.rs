//! Shared helpers for tests/data_*.rs: unique temp folders and a hand-assembled TIFF writer for the
//! variants the `tiff` crate's encoder cannot write (B-sample chunky/planar, tiles, predictors, multi-page).
#![allow(dead_code)]

use std::path::Path;

pub use crate::common::TempDir;

/// Sample kinds for hand-made TIFFs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    U8,
    U16,
    U32,
    F32,
}

impl Kind {
    pub fn bytes(self) -> usize {
        match self {
            Kind::U8 => 1,
            Kind::U16 => 2,
            Kind::U32 | Kind::F32 => 4,
        }
    }
}

/// Test value of (band, row, col) for a kind; exactly representable in it.
pub fn value(kind: Kind, b: usize, r: u32, c: u32) -> f64 {
    let i = (r as u64 * 131 + c as u64 * 7 + b as u64 * 1009) as f64;
    match kind {
        Kind::U8 => (i as u64 % 256) as f64,
        Kind::U16 => (i as u64 * 37 % 65536) as f64,
        Kind::U32 => (i as u64 * 2_654_435_761 % 4_294_967_296) as f64,
        Kind::F32 => ((i * 0.1 + b as f64 / 3.0 - 7.0) as f32) as f64,
    }
}

fn push_sample(out: &mut Vec<u8>, kind: Kind, v: f64) {
    match kind {
        Kind::U8 => out.push(v as u8),
        Kind::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
        Kind::U32 => out.extend_from_slice(&(v as u32).to_le_bytes()),
        Kind::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
    }
}

/// Layout options of a hand-made TIFF.
#[derive(Debug, Clone, Copy)]
pub struct TiffSpec {
    pub width: u32,
    pub height: u32,
    pub bands: usize,
    pub kind: Kind,
    pub planar: bool,
    /// `Some((tw, th))` for tiles, else strips of `rows_per_strip`.
    pub tiles: Option<(u32, u32)>,
    pub rows_per_strip: u32,
    /// 1 none, 2 horizontal, 3 floating point.
    pub predictor: u16,
    pub lzw: bool,
    /// One band per page instead of samples per pixel.
    pub pages: bool,
}

impl TiffSpec {
    pub fn new(width: u32, height: u32, bands: usize, kind: Kind) -> TiffSpec {
        TiffSpec {
            width,
            height,
            bands,
            kind,
            planar: false,
            tiles: None,
            rows_per_strip: 3,
            predictor: 1,
            lzw: false,
            pages: false,
        }
    }
}

/// Applies a predictor to one row of `n` pixels with `spp` samples each (little-endian bytes).
fn predict_row(row: &mut [u8], kind: Kind, spp: usize, predictor: u16) {
    let bs = kind.bytes();
    let n = row.len() / bs;
    match predictor {
        2 => {
            let get = |row: &[u8], i: usize| -> u64 {
                let mut v = 0u64;
                for k in 0..bs {
                    v |= (row[i * bs + k] as u64) << (8 * k);
                }
                v
            };
            let mask = if bs == 8 { u64::MAX } else { (1u64 << (8 * bs)) - 1 };
            for i in (spp..n).rev() {
                let d = get(row, i).wrapping_sub(get(row, i - spp)) & mask;
                for k in 0..bs {
                    row[i * bs + k] = (d >> (8 * k)) as u8;
                }
            }
        }
        3 => {
            // Byte planes, most significant first, then byte differencing with stride spp.
            let mut planes = vec![0u8; row.len()];
            for i in 0..n {
                for k in 0..bs {
                    planes[k * n + i] = row[i * bs + (bs - 1 - k)];
                }
            }
            for i in (spp..planes.len()).rev() {
                planes[i] = planes[i].wrapping_sub(planes[i - spp]);
            }
            row.copy_from_slice(&planes);
        }
        _ => {}
    }
}

/// Encodes one image (page) as chunks; returns the chunk byte blobs.
fn chunks(s: &TiffSpec, bands: &[usize]) -> Vec<Vec<u8>> {
    let spp_chunk = if s.planar { 1 } else { bands.len() };
    let planes: Vec<Vec<usize>> =
        if s.planar { bands.iter().map(|&b| vec![b]).collect() } else { vec![bands.to_vec()] };
    let (cw, ch) = s.tiles.unwrap_or((s.width, s.rows_per_strip));
    let across = if s.tiles.is_some() { s.width.div_ceil(cw) } else { 1 };
    let down = s.height.div_ceil(ch);
    let mut out = Vec::new();
    for plane in &planes {
        for ty in 0..down {
            for tx in 0..across {
                let mut blob = Vec::new();
                let rows = if s.tiles.is_some() { ch } else { ch.min(s.height - ty * ch) };
                for rr in 0..rows {
                    let mut row = Vec::new();
                    for cc in 0..cw {
                        let (r, c) = (ty * ch + rr, tx * cw + cc);
                        for &b in plane {
                            let v = if r < s.height && c < s.width { value(s.kind, b, r, c) } else { 0.0 };
                            push_sample(&mut row, s.kind, v);
                        }
                    }
                    predict_row(&mut row, s.kind, spp_chunk, s.predictor);
                    blob.extend_from_slice(&row);
                }
                if s.lzw {
                    blob =
                        weezl::encode::Encoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8).encode(&blob).unwrap();
                }
                out.push(blob);
            }
        }
    }
    out
}

/// Hand-assembles a little-endian classic TIFF following `s`.
pub fn tiff_bytes(s: &TiffSpec) -> Vec<u8> {
    let pages: Vec<Vec<usize>> =
        if s.pages { (0..s.bands).map(|b| vec![b]).collect() } else { vec![(0..s.bands).collect()] };
    let mut out: Vec<u8> = b"II*\0\0\0\0\0".to_vec();
    let mut prev_next_ptr = 4usize;
    for bands in pages {
        let blobs = chunks(s, &bands);
        let mut offsets = Vec::new();
        for b in &blobs {
            offsets.push(out.len() as u32);
            out.extend_from_slice(b);
        }
        let counts: Vec<u32> = blobs.iter().map(|b| b.len() as u32).collect();
        let spp = bands.len() as u32;
        let fmt = if s.kind == Kind::F32 { 3 } else { 1 };
        // (tag, type, values): type 3 SHORT, 4 LONG.
        let mut tags: Vec<(u16, u16, Vec<u32>)> = vec![
            (256, 4, vec![s.width]),
            (257, 4, vec![s.height]),
            (258, 3, vec![s.kind.bytes() as u32 * 8; spp as usize]),
            (259, 3, vec![if s.lzw { 5 } else { 1 }]),
            (262, 3, vec![1]),
            (277, 3, vec![spp]),
            (284, 3, vec![if s.planar { 2 } else { 1 }]),
            (317, 3, vec![s.predictor as u32]),
            (339, 3, vec![fmt; spp as usize]),
        ];
        match s.tiles {
            Some((tw, th)) => {
                tags.push((322, 4, vec![tw]));
                tags.push((323, 4, vec![th]));
                tags.push((324, 4, offsets));
                tags.push((325, 4, counts));
            }
            None => {
                tags.push((273, 4, offsets));
                tags.push((278, 4, vec![s.rows_per_strip]));
                tags.push((279, 4, counts));
            }
        }
        tags.sort_by_key(|t| t.0);
        if out.len() % 2 == 1 {
            out.push(0);
        }
        let ifd = out.len();
        out[prev_next_ptr..prev_next_ptr + 4].copy_from_slice(&(ifd as u32).to_le_bytes());
        let n = tags.len();
        let mut extra_at = ifd + 2 + n * 12 + 4;
        let mut ifd_bytes = (n as u16).to_le_bytes().to_vec();
        let mut extra = Vec::new();
        for (tag, ty, vals) in &tags {
            let size = if *ty == 3 { 2 } else { 4 };
            let mut data = Vec::new();
            for v in vals {
                if *ty == 3 {
                    data.extend_from_slice(&(*v as u16).to_le_bytes());
                } else {
                    data.extend_from_slice(&v.to_le_bytes());
                }
            }
            ifd_bytes.extend_from_slice(&tag.to_le_bytes());
            ifd_bytes.extend_from_slice(&ty.to_le_bytes());
            ifd_bytes.extend_from_slice(&(vals.len() as u32).to_le_bytes());
            if vals.len() * size <= 4 {
                data.resize(4, 0);
                ifd_bytes.extend_from_slice(&data);
            } else {
                ifd_bytes.extend_from_slice(&(extra_at as u32).to_le_bytes());
                extra_at += data.len();
                extra.extend_from_slice(&data);
            }
        }
        prev_next_ptr = ifd + ifd_bytes.len();
        ifd_bytes.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&ifd_bytes);
        out.extend_from_slice(&extra);
    }
    out
}

/// Writes `transforms.json` with `frames` (each a JSON object) and extra top-level keys.
pub fn write_transforms(dir: &Path, w: u32, h: u32, extra: serde_json::Value, frames: Vec<serde_json::Value>) {
    let mut j = serde_json::json!({
        "camera_model": "PINHOLE", "fl_x": 100.0, "fl_y": 100.0, "cx": w as f64 / 2.0, "cy": h as f64 / 2.0,
        "w": w, "h": h, "frames": frames,
    });
    if let (Some(o), Some(e)) = (j.as_object_mut(), extra.as_object()) {
        for (k, v) in e {
            o.insert(k.clone(), v.clone());
        }
    }
    std::fs::write(dir.join("transforms.json"), serde_json::to_string_pretty(&j).unwrap()).unwrap();
}

/// A frame object with an identity-rotation pose at `x` and a split.
pub fn frame(file: &str, x: f64, split: &str) -> serde_json::Value {
    serde_json::json!({"file_path": file, "split": split,
        "transform_matrix": [[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]})
}

/// `n` band entries named b0.. with centres 400 + 50 i.
pub fn bands_json(n: usize) -> serde_json::Value {
    serde_json::Value::Array(
        (0..n).map(|i| serde_json::json!({"name": format!("b{i}"), "center_nm": 400.0 + 50.0 * i as f64})).collect(),
    )
}
