//! Image file dispatch: picks the decoder from the file's magic bytes (TIFF, OpenEXR, else PNG/JPEG through
//! the `image` crate), and turns any decoder panic into an error.
//!
//! Why `catch_unwind`: the `exr` and `image` crates (and rarely `tiff`) have had panics on corrupt input
//! (slice indexing and arithmetic overflow in block decoders). A dataset with one corrupt file must give a
//! `DataError` naming that file, not abort training, so every decode runs under `catch_unwind`; the decoders
//! own all their state, so nothing observable is left inconsistent after an unwind.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use super::raster::Raster;
use super::xmp::XmpBand;

/// Metadata a file carries about its bands, used when `transforms.json` does not say.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FileMeta {
    /// Band identity from XMP (TIFF tag 700).
    pub xmp: Option<XmpBand>,
    /// Mean of the EXIF/DNG BlackLevel tag (50714), in stored units.
    pub black_level: Option<f64>,
    /// Channel names in file order (OpenEXR only).
    pub channel_names: Vec<String>,
    /// The channel that is alpha, when the file flags one (PNG grey+alpha and RGBA; TIFF ExtraSamples 1 or 2;
    /// an OpenEXR channel named `A`). It is one of the raster's bands as decoded; the loader takes it out.
    pub alpha: Option<AlphaChannel>,
}

/// Which decoded channel is alpha, and whether the colour is premultiplied by it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AlphaChannel {
    pub index: usize,
    /// Associated (premultiplied) alpha: TIFF ExtraSamples 1 and OpenEXR. Straight alpha: PNG, TIFF ExtraSamples 2.
    pub associated: bool,
}

/// A decoded file: samples in their stored type (identity scaling) plus metadata.
#[derive(Debug, Clone)]
pub struct DecodedImage {
    pub raster: Raster,
    pub meta: FileMeta,
}

/// The container a file uses, from its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    Tiff,
    Exr,
    Other,
}

pub fn sniff(bytes: &[u8]) -> FileKind {
    match bytes {
        [b'I', b'I', 42 | 43, 0, ..] | [b'M', b'M', 0, 42 | 43, ..] => FileKind::Tiff,
        [0x76, 0x2f, 0x31, 0x01, ..] => FileKind::Exr,
        _ => FileKind::Other,
    }
}

/// Reads any supported image file. `max_bytes` bounds the decoded size (corrupt headers cannot make it
/// allocate more). Never panics.
pub fn read_image_file(path: &Path, max_bytes: usize) -> Result<DecodedImage, String> {
    let mut head = [0u8; 4];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| e.to_string())?;
        let n = f.read(&mut head).map_err(|e| e.to_string())?;
        if n < 4 {
            return Err("file too short to be an image".into());
        }
    }
    let kind = sniff(&head);
    guarded(|| match kind {
        FileKind::Tiff => super::tiff_reader::read_tiff(path, max_bytes),
        FileKind::Exr => super::exr_reader::read_exr(path, max_bytes),
        FileKind::Other => super::png_reader::read_png_jpeg(path, max_bytes),
    })
}

/// Same as [`read_image_file`] on bytes in memory.
pub fn read_image_bytes(bytes: &[u8], max_bytes: usize) -> Result<DecodedImage, String> {
    if bytes.len() < 4 {
        return Err("file too short to be an image".into());
    }
    guarded(|| match sniff(bytes) {
        FileKind::Tiff => super::tiff_reader::read_tiff_bytes(bytes, max_bytes),
        FileKind::Exr => super::exr_reader::read_exr_from(std::io::Cursor::new(bytes), max_bytes),
        FileKind::Other => super::png_reader::read_png_jpeg_bytes(bytes, max_bytes),
    })
}

/// Runs a decoder, turning a panic into an error message.
pub fn guarded<T>(f: impl FnOnce() -> Result<T, String>) -> Result<T, String> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(format!("decoder panicked on corrupt input: {msg}"))
        }
    }
}
