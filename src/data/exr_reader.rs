//! OpenEXR reader on the `exr` crate (pure Rust, the reference Rust implementation, all compressions).
//! Reads the first layer at its largest resolution level, keeps f16 channels as f16 (f32 when channel types
//! are mixed, u32 when all are u32), pixel-interleaved in file order (OpenEXR stores channels sorted by
//! name); matching channels to bands by name is done by the loader from `FileMeta::channel_names`.

use std::io::{BufReader, Read, Seek};
use std::path::Path;

use exr::prelude::*;
use half::f16;

use super::raster::{Raster, Samples};
use super::reader::{AlphaChannel, DecodedImage, FileMeta};

pub fn read_exr(path: &Path, max_bytes: usize) -> std::result::Result<DecodedImage, String> {
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    read_exr_from(BufReader::new(f), max_bytes)
}

pub fn read_exr_from<R: Read + Seek>(reader: R, max_bytes: usize) -> std::result::Result<DecodedImage, String> {
    // Check the header's size before the pixel data is allocated.
    let mut reader = reader;
    let meta = exr::meta::MetaData::read_from_buffered(&mut reader, false).map_err(|e| e.to_string())?;
    for h in &meta.headers {
        let px = h.layer_size.area() as u128;
        let bytes: u128 = h.channels.list.iter().map(|c| px * c.sample_type.bytes_per_sample() as u128).sum();
        if bytes > max_bytes as u128 {
            return Err(format!(
                "EXR layer of {}x{} exceeds the allowed {max_bytes} bytes",
                h.layer_size.width(),
                h.layer_size.height()
            ));
        }
    }
    reader.rewind().map_err(|e| e.to_string())?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_buffered(reader)
        .map_err(|e| e.to_string())?;
    let layer = image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let chans = &layer.channel_data.list;
    let bands = chans.len();
    let pixels = w * h;
    if bands == 0 {
        return Err("EXR has no channels".into());
    }
    let names: Vec<String> = chans.iter().map(|c| c.name.to_string()).collect();
    let all_f16 = chans.iter().all(|c| matches!(c.sample_data, FlatSamples::F16(_)));
    let all_u32 = chans.iter().all(|c| matches!(c.sample_data, FlatSamples::U32(_)));
    for c in chans {
        if c.sample_data.len() != pixels {
            return Err(format!("channel `{}` is subsampled (unsupported)", c.name));
        }
    }
    let samples = if all_f16 {
        let mut v = vec![f16::ZERO; pixels * bands];
        for (b, c) in chans.iter().enumerate() {
            if let FlatSamples::F16(s) = &c.sample_data {
                for (p, x) in s.iter().enumerate() {
                    v[p * bands + b] = *x;
                }
            }
        }
        Samples::F16(v)
    } else if all_u32 {
        let mut v = vec![0u32; pixels * bands];
        for (b, c) in chans.iter().enumerate() {
            if let FlatSamples::U32(s) = &c.sample_data {
                for (p, x) in s.iter().enumerate() {
                    v[p * bands + b] = *x;
                }
            }
        }
        Samples::U32(v)
    } else {
        let mut v = vec![0f32; pixels * bands];
        for (b, c) in chans.iter().enumerate() {
            for p in 0..pixels {
                v[p * bands + b] = match &c.sample_data {
                    FlatSamples::F16(s) => s[p].to_f32(),
                    FlatSamples::F32(s) => s[p],
                    FlatSamples::U32(s) => s[p] as f32,
                };
            }
        }
        Samples::F32(v)
    };
    let raster = Raster::new(w as u32, h as u32, bands, samples).ok_or("EXR sample count does not match its size")?;
    // OpenEXR's alpha is the channel `A` (or `layer.A`), and its colour is premultiplied by it.
    let alpha = (bands > 1)
        .then(|| names.iter().position(|n| n.rsplit('.').next().unwrap_or(n) == "A"))
        .flatten()
        .map(|index| AlphaChannel { index, associated: true });
    Ok(DecodedImage { raster, meta: FileMeta { channel_names: names, alpha, ..FileMeta::default() } })
}
