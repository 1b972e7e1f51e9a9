//! PNG/JPEG reader on the `image` crate (built with only its `png` and `jpeg` features). 8-bit files stay
//! u8 and 16-bit PNGs stay u16: the decoder's native buffer is kept, never converted through 8 bits.

use std::path::Path;

use image::DynamicImage;

use super::raster::{Raster, Samples};
use super::reader::{AlphaChannel, DecodedImage, FileMeta};

pub fn read_png_jpeg(path: &Path, max_bytes: usize) -> Result<DecodedImage, String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    read_png_jpeg_bytes(&bytes, max_bytes)
}

pub fn read_png_jpeg_bytes(bytes: &[u8], max_bytes: usize) -> Result<DecodedImage, String> {
    let mut reader =
        image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string())?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_bytes as u64);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| e.to_string())?;
    let (w, h) = (img.width(), img.height());
    let (bands, samples) = match img {
        DynamicImage::ImageLuma8(b) => (1, Samples::U8(b.into_raw())),
        DynamicImage::ImageLumaA8(b) => (2, Samples::U8(b.into_raw())),
        DynamicImage::ImageRgb8(b) => (3, Samples::U8(b.into_raw())),
        DynamicImage::ImageRgba8(b) => (4, Samples::U8(b.into_raw())),
        DynamicImage::ImageLuma16(b) => (1, Samples::U16(b.into_raw())),
        DynamicImage::ImageLumaA16(b) => (2, Samples::U16(b.into_raw())),
        DynamicImage::ImageRgb16(b) => (3, Samples::U16(b.into_raw())),
        DynamicImage::ImageRgba16(b) => (4, Samples::U16(b.into_raw())),
        DynamicImage::ImageRgb32F(b) => (3, Samples::F32(b.into_raw())),
        DynamicImage::ImageRgba32F(b) => (4, Samples::F32(b.into_raw())),
        _ => return Err("unsupported PNG/JPEG pixel layout".into()),
    };
    let raster = Raster::new(w, h, bands, samples).ok_or("decoded size mismatch")?;
    // Grey+alpha and RGBA: the last channel is straight (unassociated) alpha, as PNG defines it.
    let alpha = matches!(bands, 2 | 4).then_some(AlphaChannel { index: bands - 1, associated: false });
    Ok(DecodedImage { raster, meta: FileMeta { alpha, ..FileMeta::default() } })
}
