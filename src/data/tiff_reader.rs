//! TIFF reader on the `tiff` crate (image-rs; pure Rust, maintained, and in 0.11 it decodes everything
//! dataset.md lists: 8/16/32-bit unsigned and 16/32-bit float samples, chunky and planar layouts, strips and
//! tiles, none/LZW/Deflate/PackBits, horizontal and floating-point predictors). What this file adds on top:
//! planar-to-interleaved reordering, multi-page files with one band per page, BlackLevel (EXIF 50714) and XMP
//! (tag 700) extraction, and a size limit taken from the expected image size.
//!
//! Reduced-resolution pages (NewSubfileType bit 0, e.g. GeoTIFF overviews) are skipped. Packed 12-bit and
//! signed samples are rejected with a `Decode` error naming the file.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{ifd::Value, Decoder, DecodingResult, Limits};
use tiff::tags::{PlanarConfiguration, Tag};

use super::raster::{Raster, Samples};
use super::reader::{AlphaChannel, DecodedImage, FileMeta};
use super::xmp::parse_xmp_band;

const TAG_XMP: u16 = 700;
const TAG_BLACK_LEVEL: u16 = 50714;

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// Reads a whole TIFF into a `Raster` (identity scaling) plus band metadata. `max_bytes` bounds allocations.
pub fn read_tiff(path: &Path, max_bytes: usize) -> Result<DecodedImage, String> {
    let file = File::open(path).map_err(err)?;
    match read_tiff_from(BufReader::new(file), max_bytes) {
        Err(e) if e == NEEDS_GRAY => {
            let bytes = std::fs::read(path).map_err(err)?;
            read_tiff_from(std::io::Cursor::new(as_multiband(&bytes)), max_bytes)
        }
        r => r,
    }
}

/// Reads TIFF bytes in memory.
pub fn read_tiff_bytes(bytes: &[u8], max_bytes: usize) -> Result<DecodedImage, String> {
    match read_tiff_from(std::io::Cursor::new(bytes), max_bytes) {
        Err(e) if e == NEEDS_GRAY => read_tiff_from(std::io::Cursor::new(as_multiband(bytes)), max_bytes),
        r => r,
    }
}

/// Marker error: the page is RGB/CMYK with extra non-alpha samples, which the `tiff` crate decodes as its
/// colour samples only (it drops the extras: a 5-band GeoTIFF written as RGB + 2 extra samples comes back
/// with 3). We then re-read an in-memory copy whose PhotometricInterpretation is patched to BlackIsZero,
/// which the crate decodes as `Multiband` with every sample. The user's file is never modified.
const NEEDS_GRAY: &str = "tiff: photometric RGB/CMYK with extra samples";

/// A copy of `bytes` with every IFD's PhotometricInterpretation (tag 262) set to 1 (BlackIsZero).
fn as_multiband(bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let le = b.starts_with(b"II");
    let rd = |b: &[u8], o: usize, n: usize| -> Option<u64> {
        let s = b.get(o..o + n)?;
        let mut v = 0u64;
        for i in 0..n {
            let byte = if le { s[n - 1 - i] } else { s[i] } as u64;
            v = (v << 8) | byte;
        }
        Some(v)
    };
    let big = rd(&b, 2, 2) == Some(43);
    let (mut ifd, cnt_sz, ent_sz, val_off) = if big {
        (rd(&b, 8, 8).unwrap_or(0) as usize, 8, 20, 12)
    } else {
        (rd(&b, 4, 4).unwrap_or(0) as usize, 2, 12, 8)
    };
    for _ in 0..4096 {
        let Some(n) = rd(&b, ifd, cnt_sz) else { break };
        for e in 0..n.min(4096) as usize {
            let o = ifd + cnt_sz + e * ent_sz;
            if rd(&b, o, 2) == Some(262) && rd(&b, o + 2, 2) == Some(3) && o + val_off + 2 <= b.len() {
                let v: [u8; 2] = if le { [1, 0] } else { [0, 1] };
                b[o + val_off..o + val_off + 2].copy_from_slice(&v);
            }
        }
        let next_o = ifd + cnt_sz + n as usize * ent_sz;
        match rd(&b, next_o, if big { 8 } else { 4 }) {
            Some(next) if next != 0 && (next as usize) != ifd => ifd = next as usize,
            _ => break,
        }
    }
    b
}

/// Same as [`read_tiff`] for any seekable reader (used by the mutation tests on in-memory bytes).
pub fn read_tiff_from<R: std::io::Read + std::io::Seek>(reader: R, max_bytes: usize) -> Result<DecodedImage, String> {
    let mut limits = Limits::default();
    limits.decoding_buffer_size = max_bytes.max(1 << 20);
    limits.intermediate_buffer_size = max_bytes.max(1 << 20);
    let mut dec = Decoder::new(reader).map_err(err)?.with_limits(limits);

    let mut meta = FileMeta::default();
    let mut pages: Vec<(u32, u32, usize, Samples)> = Vec::new();
    let mut page_index = 0usize;
    let mut extra: Vec<u16> = Vec::new();
    loop {
        let subfile = dec.find_tag_unsigned::<u32>(Tag::NewSubfileType).map_err(err)?.unwrap_or(0);
        if subfile & 1 == 0 {
            if pages.is_empty() {
                if let Ok(Some(v)) = dec.find_tag(Tag::Unknown(TAG_XMP)) {
                    if let Ok(bytes) = v.into_u8_vec() {
                        meta.xmp = parse_xmp_band(&bytes);
                    }
                }
                if let Ok(Some(v)) = dec.find_tag(Tag::Unknown(TAG_BLACK_LEVEL)) {
                    let vals = value_to_f64s(v);
                    if !vals.is_empty() {
                        meta.black_level = Some(vals.iter().sum::<f64>() / vals.len() as f64);
                    }
                }
                extra = dec.find_tag_unsigned_vec::<u16>(Tag::ExtraSamples).ok().flatten().unwrap_or_default();
            }
            pages.push(read_page(&mut dec, max_bytes)?);
            if pages.len() == 1 {
                meta.alpha = alpha_channel(pages[0].2, &extra);
            }
            // Only multi-page files of single-sample pages are band stacks; stop after page 1 otherwise.
            if pages[0].2 != 1 {
                break;
            }
        }
        page_index += 1;
        if !dec.more_images() || page_index > 4096 {
            break;
        }
        dec.next_image().map_err(err)?;
    }
    // Keep only pages of the first page's size (a band stack); others (thumbnails, masks) are ignored.
    let (w, h, b0, _) = (pages[0].0, pages[0].1, pages[0].2, ());
    let same: Vec<_> = pages.into_iter().filter(|p| p.0 == w && p.1 == h && p.2 == b0).collect();
    let raster = if same.len() == 1 {
        let (w, h, b, s) = same.into_iter().next().expect("one page");
        Raster::new(w, h, b, s).ok_or("sample count does not match the image size")?
    } else {
        interleave_pages(w, h, same)?
    };
    Ok(DecodedImage { raster, meta })
}

/// The alpha channel ExtraSamples (tag 338) flags on a page of `samples` samples: the extra samples are the last
/// ones, after the colour samples (so this holds for RGB + alpha and for a B-band MinIsBlack image + alpha alike);
/// 1 is associated (premultiplied) alpha, 2 unassociated (straight) alpha. The first one flagged is used.
fn alpha_channel(samples: usize, extra: &[u16]) -> Option<AlphaChannel> {
    let base = samples.checked_sub(extra.len())?;
    extra.iter().position(|&e| e == 1 || e == 2).map(|k| AlphaChannel { index: base + k, associated: extra[k] == 1 })
}

fn read_page<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
    max_bytes: usize,
) -> Result<(u32, u32, usize, Samples), String> {
    let (w, h) = dec.dimensions().map_err(err)?;
    let color = dec.colortype().map_err(err)?;
    // SamplesPerPixel, not the colour type: an RGB image with extra samples (e.g. a 5-band GeoTIFF written
    // as RGB + 2 extra) reports 3 colour samples but stores 5.
    let samples =
        dec.find_tag_unsigned::<u16>(Tag::SamplesPerPixel).map_err(err)?.unwrap_or(color.num_samples()) as usize;
    if samples == 0 {
        return Err("SamplesPerPixel is 0".into());
    }
    let photometric = dec.find_tag_unsigned::<u16>(Tag::PhotometricInterpretation).map_err(err)?.unwrap_or(1);
    if samples > color.num_samples() as usize && matches!(photometric, 2 | 5) {
        return Err(NEEDS_GRAY.into());
    }
    let bits = color.bit_depth();
    if !matches!(bits, 8 | 16 | 32) {
        return Err(format!("unsupported bit depth {bits} (only 8/16/32-bit samples)"));
    }
    let total = (w as u128) * (h as u128) * samples as u128 * (bits as u128 / 8);
    if total > max_bytes as u128 {
        return Err(format!("image {w}x{h}x{samples} at {bits} bits exceeds the allowed {max_bytes} bytes"));
    }
    let planar =
        dec.find_tag_unsigned::<u16>(Tag::PlanarConfiguration).map_err(err)?.and_then(PlanarConfiguration::from_u16)
            == Some(PlanarConfiguration::Planar);
    if dec.get_chunk_type() == tiff::decoder::ChunkType::Tile {
        let s = read_tiles(dec, w, h, samples, planar)?;
        return Ok((w, h, samples, s));
    }
    let mut result = DecodingResult::U8(vec![]);
    dec.read_image_to_buffer(&mut result).map_err(err)?;
    let s = match result {
        DecodingResult::U8(v) => Samples::U8(v),
        DecodingResult::U16(v) => Samples::U16(v),
        DecodingResult::U32(v) => Samples::U32(v),
        DecodingResult::F16(v) => Samples::F16(v),
        DecodingResult::F32(v) => Samples::F32(v),
        _ => return Err("unsupported sample format (signed or 64-bit samples)".into()),
    };
    let n = w as usize * h as usize * samples;
    if s.len() < n {
        return Err(format!("decoded {} samples, expected {n} (truncated planar data?)", s.len()));
    }
    let s = if planar && samples > 1 { planar_to_chunky(&s, w as usize * h as usize, samples) } else { truncate(s, n) };
    Ok((w, h, samples, s))
}

fn to_samples(r: DecodingResult) -> Result<Samples, String> {
    Ok(match r {
        DecodingResult::U8(v) => Samples::U8(v),
        DecodingResult::U16(v) => Samples::U16(v),
        DecodingResult::U32(v) => Samples::U32(v),
        DecodingResult::F16(v) => Samples::F16(v),
        DecodingResult::F32(v) => Samples::F32(v),
        _ => return Err("unsupported sample format (signed or 64-bit samples)".into()),
    })
}

/// Tiled images are assembled tile by tile with `read_chunk`: `tiff` 0.11's whole-image path asserts
/// (panics) on planar images with partial edge tiles, and fails on LZW edge tiles of multi-sample chunky
/// images, while its per-tile path decodes both.
fn read_tiles<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
    w: u32,
    h: u32,
    samples: usize,
    planar: bool,
) -> Result<Samples, String> {
    let (tw, th) = dec.chunk_dimensions();
    if tw == 0 || th == 0 {
        return Err("zero tile size".into());
    }
    let across = w.div_ceil(tw);
    let down = h.div_ceil(th);
    let per_plane = across * down;
    let (planes, spp) = if planar { (samples, 1) } else { (1, samples) };
    let mut out: Option<Samples> = None;
    for p in 0..planes {
        for t in 0..per_plane {
            let (tx, ty) = (t % across, t / across);
            let dw = tw.min(w - tx * tw) as usize;
            let dh = th.min(h - ty * th) as usize;
            let chunk = to_samples(dec.read_chunk(p as u32 * per_plane + t).map_err(err)?)?;
            if chunk.len() < dw * dh * spp {
                return Err(format!("tile {t} decoded {} samples, expected {}", chunk.len(), dw * dh * spp));
            }
            let o = out.get_or_insert_with(|| Samples::zeros(chunk.sample_type(), w as usize * h as usize * samples));
            for r in 0..dh {
                for c in 0..dw {
                    let px = (ty as usize * th as usize + r) * w as usize + tx as usize * tw as usize + c;
                    for k in 0..spp {
                        let src = (r * dw + c) * spp + k;
                        if !o.copy_from(px * samples + p + k, &chunk, src) {
                            return Err("tiles of different sample types".into());
                        }
                    }
                }
            }
        }
    }
    out.ok_or_else(|| "image has no tiles".to_string())
}

fn truncate(s: Samples, n: usize) -> Samples {
    match s {
        Samples::U8(mut v) => {
            v.truncate(n);
            Samples::U8(v)
        }
        Samples::U16(mut v) => {
            v.truncate(n);
            Samples::U16(v)
        }
        Samples::U32(mut v) => {
            v.truncate(n);
            Samples::U32(v)
        }
        Samples::F16(mut v) => {
            v.truncate(n);
            Samples::F16(v)
        }
        Samples::F32(mut v) => {
            v.truncate(n);
            Samples::F32(v)
        }
    }
}

/// Band-major planes (`[b][pixel]`) to pixel-interleaved (`[pixel][b]`).
fn planar_to_chunky(s: &Samples, pixels: usize, bands: usize) -> Samples {
    let mut out = Samples::zeros(s.sample_type(), pixels * bands);
    for b in 0..bands {
        for p in 0..pixels {
            out.copy_from(p * bands + b, s, b * pixels + p);
        }
    }
    out
}

fn interleave_pages(w: u32, h: u32, pages: Vec<(u32, u32, usize, Samples)>) -> Result<Raster, String> {
    let bands = pages.len();
    let pixels = w as usize * h as usize;
    let ty = pages[0].3.sample_type();
    let mut out = Samples::zeros(ty, pixels * bands);
    for (b, page) in pages.iter().enumerate() {
        if page.3.sample_type() != ty {
            return Err(format!("page {b} has a different sample type than page 0"));
        }
        for p in 0..pixels {
            out.copy_from(p * bands + b, &page.3, p);
        }
    }
    Raster::new(w, h, bands, out).ok_or_else(|| "page sizes do not match".to_string())
}

fn value_to_f64s(v: Value) -> Vec<f64> {
    match v {
        Value::List(l) => l.into_iter().flat_map(value_to_f64s).collect(),
        Value::Byte(x) => vec![x as f64],
        Value::Short(x) => vec![x as f64],
        Value::Unsigned(x) => vec![x as f64],
        Value::UnsignedBig(x) => vec![x as f64],
        Value::Float(x) => vec![x as f64],
        Value::Double(x) => vec![x],
        Value::Rational(n, d) if d != 0 => vec![n as f64 / d as f64],
        _ => vec![],
    }
}
