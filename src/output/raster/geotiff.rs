//! Multi-band float32 GeoTIFF writer (hand-written: the `tiff` crate's encoder has no B-sample float colour type
//! and no way to add GDAL's private tags).
//!
//! Layout: little-endian classic TIFF (BigTIFF when the file would pass 4 GiB, or on request), one IFD,
//! uncompressed, pixel-interleaved (`PlanarConfiguration` 1, GDAL's default `INTERLEAVE=PIXEL`), strips of about
//! 256 KiB, `SampleFormat` 3 (IEEE float) × B, `PhotometricInterpretation` 1 (MinIsBlack) with B − 1
//! unspecified `ExtraSamples` (as GDAL writes it, so libtiff does not warn).
//!
//! GDAL-specific tags:
//! - `GDAL_METADATA` (42112): XML with, per band (`sample="i"`), `DESCRIPTION` (role `description`, e.g.
//!   "NIR 840nm", which `gdalinfo` shows as the band description), `wavelength`, `wavelength_units` (nm), `fwhm`,
//!   and GDAL's IMAGERY domain `CENTRAL_WAVELENGTH_UM` / `FWHM_UM`; plus dataset-level items given by the caller.
//! - `GDAL_NODATA` (42113): the nodata value as ASCII ("nan" for NaN) when given.
//!
//! Georeferencing (optional): `ModelPixelScale` (33550), `ModelTiepoint` (33922) for a north-up grid whose
//! top-left pixel corner is `origin`, and a `GeoKeyDirectory` (34735) with `GTRasterTypeGeoKey` PixelIsArea and
//! the EPSG code as `ProjectedCSTypeGeoKey` (or `GeographicTypeGeoKey` for EPSG 4000–4999).

use std::io::Write;
use std::path::Path;

use crate::output::image::{band_description, fmt_nm};
use crate::output::{atomic, Band, OutputError, Result, SpectralImage};

pub const TAG_GDAL_METADATA: u16 = 42112;
pub const TAG_GDAL_NODATA: u16 = 42113;

/// A north-up grid: `origin` = (x, y) of the top-left corner of the top-left pixel; `pixel_size` = (width,
/// height) of a pixel, both positive (y decreases downwards).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeoReference {
    pub origin: [f64; 2],
    pub pixel_size: [f64; 2],
    /// EPSG code of the CRS (e.g. 32650 for UTM 50N, 4326 for WGS 84).
    pub epsg: Option<u16>,
}

impl GeoReference {
    /// A north-up grid in `crs` (a dataset's `crs`, or none): GeoTIFF's keys carry an EPSG code, so a CRS known
    /// only by its WKT is refused, named.
    pub fn in_crs(origin: [f64; 2], pixel_size: [f64; 2], crs: Option<&crate::geo::Crs>) -> Result<Self> {
        let epsg = match crs {
            None => None,
            Some(c) => Some(c.epsg.and_then(|e| u16::try_from(e).ok()).ok_or_else(|| {
                OutputError::invalid(
                    "crs",
                    format!("{}: GeoTIFF keys need an EPSG code; give the dataset's crs as EPSG:n", c.describe()),
                )
            })?),
        };
        Ok(GeoReference { origin, pixel_size, epsg })
    }
}

/// GeoTIFF options.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GeoTiffOptions {
    /// Written as `GDAL_NODATA` (NaN allowed).
    pub nodata: Option<f64>,
    pub georef: Option<GeoReference>,
    /// `Some(true)` forces BigTIFF; `None` picks it when the file would exceed 4 GiB.
    pub bigtiff: Option<bool>,
    /// Dataset-level GDAL metadata items (name, value).
    pub metadata: Vec<(String, String)>,
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The `GDAL_METADATA` XML for `bands` plus dataset-level `items`.
pub fn gdal_metadata_xml(bands: &[Band], items: &[(String, String)]) -> String {
    let mut s = String::from("<GDALMetadata>\n");
    let mut item = |name: &str, sample: Option<usize>, extra: &str, value: &str| {
        let sample = sample.map(|i| format!(" sample=\"{i}\"")).unwrap_or_default();
        s += &format!("  <Item name=\"{}\"{sample}{extra}>{}</Item>\n", xml_escape(name), xml_escape(value));
    };
    for (k, v) in items {
        item(k, None, "", v);
    }
    for (i, b) in bands.iter().enumerate() {
        item("DESCRIPTION", Some(i), " role=\"description\"", &band_description(b));
        item("band_name", Some(i), "", &b.name);
        if let Some(c) = b.center_nm {
            item("wavelength", Some(i), "", &fmt_nm(c));
            item("wavelength_units", Some(i), "", "nm");
            item("CENTRAL_WAVELENGTH_UM", Some(i), " domain=\"IMAGERY\"", &format!("{}", c / 1000.0));
        }
        if let Some(f) = b.fwhm_nm {
            item("fwhm", Some(i), "", &fmt_nm(f));
            item("FWHM_UM", Some(i), " domain=\"IMAGERY\"", &format!("{}", f / 1000.0));
        }
    }
    s += "</GDALMetadata>";
    s
}

/// GDAL's text form of a nodata value.
pub fn nodata_string(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{v}")
    }
}

const SHORT: u16 = 3;
const LONG: u16 = 4;
const ASCII: u16 = 2;
const DOUBLE: u16 = 12;
const LONG8: u16 = 16;

struct Entry {
    tag: u16,
    typ: u16,
    count: u64,
    bytes: Vec<u8>,
}

fn shorts(tag: u16, v: &[u16]) -> Entry {
    Entry { tag, typ: SHORT, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn longs(tag: u16, v: &[u32]) -> Entry {
    Entry { tag, typ: LONG, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn long8s(tag: u16, v: &[u64]) -> Entry {
    Entry { tag, typ: LONG8, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn doubles(tag: u16, v: &[f64]) -> Entry {
    Entry { tag, typ: DOUBLE, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn ascii(tag: u16, s: &str) -> Entry {
    let mut bytes = s.as_bytes().to_vec();
    bytes.push(0);
    Entry { tag, typ: ASCII, count: bytes.len() as u64, bytes }
}

/// Writes `img` as a float32 GeoTIFF at `path` (atomically).
pub fn write_geotiff(path: &Path, img: &SpectralImage, opts: &GeoTiffOptions) -> Result<()> {
    img.validate()?;
    let nb = img.n_bands();
    if nb > u16::MAX as usize {
        return Err(OutputError::invalid("image", format!("{nb} bands do not fit a TIFF")));
    }
    let (w, h) = (img.width, img.height);
    if w > u32::MAX as usize || h > u32::MAX as usize {
        return Err(OutputError::invalid("image", format!("{w}x{h} is too large for TIFF")));
    }
    let row_bytes = (w * nb * 4) as u64;
    let rows_per_strip = ((256 * 1024) / row_bytes).clamp(1, h as u64) as usize;
    let n_strips = h.div_ceil(rows_per_strip);
    let data_bytes = row_bytes * h as u64;
    let big = opts.bigtiff.unwrap_or(data_bytes + (1 << 20) + 64 * n_strips as u64 > u32::MAX as u64);
    let header_len: u64 = if big { 16 } else { 8 };

    // Strip table.
    let mut offsets = Vec::with_capacity(n_strips);
    let mut counts = Vec::with_capacity(n_strips);
    for s in 0..n_strips {
        let rows = rows_per_strip.min(h - s * rows_per_strip) as u64;
        offsets.push(header_len + s as u64 * rows_per_strip as u64 * row_bytes);
        counts.push(rows * row_bytes);
    }

    let mut entries = vec![
        longs(256, &[w as u32]),
        longs(257, &[h as u32]),
        shorts(258, &vec![32; nb]),
        shorts(259, &[1]),
        shorts(262, &[1]),
        if big { long8s(273, &offsets) } else { longs(273, &offsets.iter().map(|&o| o as u32).collect::<Vec<_>>()) },
        shorts(277, &[nb as u16]),
        longs(278, &[rows_per_strip as u32]),
        if big { long8s(279, &counts) } else { longs(279, &counts.iter().map(|&o| o as u32).collect::<Vec<_>>()) },
        shorts(284, &[1]),
        ascii(305, "msnerf"),
        shorts(339, &vec![3; nb]),
    ];
    if nb > 1 {
        entries.push(shorts(338, &vec![0; nb - 1]));
    }
    if let Some(g) = &opts.georef {
        if !(g.pixel_size[0] > 0.0 && g.pixel_size[1] > 0.0) {
            return Err(OutputError::invalid("georef.pixel_size", format!("must be positive, got {:?}", g.pixel_size)));
        }
        entries.push(doubles(33550, &[g.pixel_size[0], g.pixel_size[1], 0.0]));
        entries.push(doubles(33922, &[0.0, 0.0, 0.0, g.origin[0], g.origin[1], 0.0]));
        let mut keys: Vec<[u16; 4]> = Vec::new();
        match g.epsg {
            Some(code) if (4000..5000).contains(&code) => {
                keys.push([1024, 0, 1, 2]);
                keys.push([1025, 0, 1, 1]);
                keys.push([2048, 0, 1, code]);
            }
            Some(code) => {
                keys.push([1024, 0, 1, 1]);
                keys.push([1025, 0, 1, 1]);
                keys.push([3072, 0, 1, code]);
            }
            None => keys.push([1025, 0, 1, 1]),
        }
        let mut dir = vec![1u16, 1, 0, keys.len() as u16];
        keys.iter().for_each(|k| dir.extend_from_slice(k));
        entries.push(shorts(34735, &dir));
    }
    entries.push(ascii(TAG_GDAL_METADATA, &gdal_metadata_xml(&img.bands, &opts.metadata)));
    if let Some(nd) = opts.nodata {
        entries.push(ascii(TAG_GDAL_NODATA, &nodata_string(nd)));
    }
    entries.sort_by_key(|e| e.tag);

    // IFD after the pixel data, then the out-of-line values.
    let ifd_off = header_len + data_bytes + (data_bytes & 1);
    let (inline_max, entry_len, count_len): (usize, u64, u64) = if big { (8, 20, 8) } else { (4, 12, 2) };
    let ifd_len = count_len + entry_len * entries.len() as u64 + if big { 8 } else { 4 };
    let mut ext_off = ifd_off + ifd_len;
    let mut ifd = Vec::with_capacity(ifd_len as usize);
    let mut ext = Vec::new();
    if big {
        ifd.extend_from_slice(&(entries.len() as u64).to_le_bytes());
    } else {
        ifd.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    }
    for e in &entries {
        ifd.extend_from_slice(&e.tag.to_le_bytes());
        ifd.extend_from_slice(&e.typ.to_le_bytes());
        if big {
            ifd.extend_from_slice(&e.count.to_le_bytes());
        } else {
            ifd.extend_from_slice(&(e.count as u32).to_le_bytes());
        }
        if e.bytes.len() <= inline_max {
            let mut v = e.bytes.clone();
            v.resize(inline_max, 0);
            ifd.extend_from_slice(&v);
        } else {
            if big {
                ifd.extend_from_slice(&ext_off.to_le_bytes());
            } else {
                let o = u32::try_from(ext_off).map_err(|_| OutputError::write(path, "classic TIFF offset overflow"))?;
                ifd.extend_from_slice(&o.to_le_bytes());
            }
            ext.extend_from_slice(&e.bytes);
            ext_off += e.bytes.len() as u64;
            if e.bytes.len() % 2 == 1 {
                ext.push(0);
                ext_off += 1;
            }
        }
    }
    ifd.extend_from_slice(&if big { vec![0u8; 8] } else { vec![0u8; 4] });
    if !big && ext_off > u32::MAX as u64 {
        return Err(OutputError::write(path, "file exceeds 4 GiB: use bigtiff"));
    }

    let n = img.n_pixels();
    Ok(atomic::write_with(path, |f| {
        if big {
            f.write_all(b"II\x2b\x00\x08\x00\x00\x00")?;
            f.write_all(&ifd_off.to_le_bytes())?;
        } else {
            f.write_all(b"II\x2a\x00")?;
            f.write_all(&(ifd_off as u32).to_le_bytes())?;
        }
        let mut row = Vec::with_capacity(row_bytes as usize);
        for y in 0..h {
            row.clear();
            for x in 0..w {
                for b in 0..nb {
                    row.extend_from_slice(&img.data[b * n + y * w + x].to_le_bytes());
                }
            }
            f.write_all(&row)?;
        }
        if data_bytes & 1 == 1 {
            f.write_all(&[0])?;
        }
        f.write_all(&ifd)?;
        f.write_all(&ext)
    })?)
}
