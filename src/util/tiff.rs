//! Plain multi-band TIFF files as datasets store them: little-endian classic TIFF, uncompressed, chunky (B samples
//! per pixel, PhotometricInterpretation BlackIsZero, B - 1 unspecified ExtraSamples, as GDAL writes them), strips of
//! about 64 KiB; float32 or uint16 samples. Used by `msnerf simulate` and `msnerf import rig`.

use std::path::Path;

/// Sample data for [`write_tiff`].
pub enum TiffData<'a> {
    F32(&'a [f32]),
    U16(&'a [u16]),
}

/// Writes a chunky `samples`-per-pixel TIFF (row-major, samples interleaved).
pub fn write_tiff(path: &Path, width: u32, height: u32, samples: usize, data: TiffData) -> std::io::Result<()> {
    std::fs::write(path, tiff_bytes(width, height, samples, data))
}

/// The TIFF file bytes (see the module doc).
pub fn tiff_bytes(width: u32, height: u32, samples: usize, data: TiffData) -> Vec<u8> {
    let (bits, fmt, payload): (u32, u32, Vec<u8>) = match data {
        TiffData::F32(v) => (32, 3, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        TiffData::U16(v) => (16, 1, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
    };
    let row_bytes = width as usize * samples * bits as usize / 8;
    let rows_per_strip = (65536 / row_bytes.max(1)).clamp(1, height as usize);
    let mut out: Vec<u8> = b"II*\0\0\0\0\0".to_vec();
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    for chunk in payload.chunks(row_bytes * rows_per_strip) {
        offsets.push(out.len() as u32);
        counts.push(chunk.len() as u32);
        out.extend_from_slice(chunk);
    }
    if out.len() % 2 == 1 {
        out.push(0);
    }
    // (tag, type 3 SHORT / 4 LONG, values), sorted by tag.
    let mut tags: Vec<(u16, u16, Vec<u32>)> = vec![
        (256, 4, vec![width]),
        (257, 4, vec![height]),
        (258, 3, vec![bits; samples]),
        (259, 3, vec![1]),
        (262, 3, vec![1]),
        (273, 4, offsets),
        (277, 3, vec![samples as u32]),
        (278, 4, vec![rows_per_strip as u32]),
        (279, 4, counts),
        (284, 3, vec![1]),
    ];
    if samples > 1 {
        tags.push((338, 3, vec![0; samples - 1]));
    }
    tags.push((339, 3, vec![fmt; samples]));
    let ifd = out.len();
    out[4..8].copy_from_slice(&(ifd as u32).to_le_bytes());
    let mut extra_at = ifd + 2 + tags.len() * 12 + 4;
    let mut ifd_bytes = (tags.len() as u16).to_le_bytes().to_vec();
    let mut extra = Vec::new();
    for (tag, ty, vals) in &tags {
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
        if data.len() <= 4 {
            data.resize(4, 0);
            ifd_bytes.extend_from_slice(&data);
        } else {
            ifd_bytes.extend_from_slice(&(extra_at as u32).to_le_bytes());
            extra_at += data.len();
            extra.extend_from_slice(&data);
        }
    }
    ifd_bytes.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&ifd_bytes);
    out.extend_from_slice(&extra);
    out
}
