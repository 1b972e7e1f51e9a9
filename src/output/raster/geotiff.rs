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

/// One IFD entry: tag, TIFF type, value count and the little-endian value bytes.
pub(crate) struct Entry {
    tag: u16,
    typ: u16,
    count: u64,
    bytes: Vec<u8>,
}

pub(crate) fn shorts(tag: u16, v: &[u16]) -> Entry {
    Entry { tag, typ: SHORT, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
pub(crate) fn longs(tag: u16, v: &[u32]) -> Entry {
    Entry { tag, typ: LONG, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
pub(crate) fn long8s(tag: u16, v: &[u64]) -> Entry {
    Entry { tag, typ: LONG8, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
fn doubles(tag: u16, v: &[f64]) -> Entry {
    Entry { tag, typ: DOUBLE, count: v.len() as u64, bytes: v.iter().flat_map(|x| x.to_le_bytes()).collect() }
}
pub(crate) fn ascii(tag: u16, s: &str) -> Entry {
    let mut bytes = s.as_bytes().to_vec();
    bytes.push(0);
    Entry { tag, typ: ASCII, count: bytes.len() as u64, bytes }
}

/// File offsets as LONG (classic) or LONG8 (BigTIFF).
pub(crate) fn offsets(tag: u16, v: &[u64], big: bool) -> Entry {
    if big {
        long8s(tag, v)
    } else {
        longs(tag, &v.iter().map(|&o| o as u32).collect::<Vec<_>>())
    }
}

/// The float32 sample layout tags for `nb` pixel-interleaved bands: BitsPerSample, Compression none,
/// MinIsBlack, SamplesPerPixel, PlanarConfiguration chunky, Software, SampleFormat float, ExtraSamples.
pub(crate) fn float_layout_entries(width: usize, height: usize, nb: usize) -> Vec<Entry> {
    let mut e = vec![
        longs(256, &[width as u32]),
        longs(257, &[height as u32]),
        shorts(258, &vec![32; nb]),
        shorts(259, &[1]),
        shorts(262, &[1]),
        shorts(277, &[nb as u16]),
        shorts(284, &[1]),
        ascii(305, "msnerf"),
        shorts(339, &vec![3; nb]),
    ];
    if nb > 1 {
        e.push(shorts(338, &vec![0; nb - 1]));
    }
    e
}

/// The georeferencing (`ModelPixelScale`, `ModelTiepoint`, `GeoKeyDirectory`), `GDAL_METADATA` and `GDAL_NODATA`
/// entries of the full-resolution image.
pub(crate) fn geo_entries(bands: &[Band], opts: &GeoTiffOptions) -> Result<Vec<Entry>> {
    let mut entries = Vec::new();
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
    entries.push(ascii(TAG_GDAL_METADATA, &gdal_metadata_xml(bands, &opts.metadata)));
    if let Some(nd) = opts.nodata {
        entries.push(ascii(TAG_GDAL_NODATA, &nodata_string(nd)));
    }
    Ok(entries)
}

/// Encodes an IFD (entries sorted by tag) that will sit at file offset `ifd_off`, followed directly by its
/// out-of-line values; `next` is the offset of the next IFD (0: the last). The length does not depend on the
/// offsets, so a layout can be sized first with zeros.
pub(crate) fn encode_ifd(mut entries: Vec<Entry>, ifd_off: u64, next: u64, big: bool, path: &Path) -> Result<Vec<u8>> {
    entries.sort_by_key(|e| e.tag);
    let (inline_max, entry_len, count_len): (usize, u64, u64) = if big { (8, 20, 8) } else { (4, 12, 2) };
    let ifd_len = count_len + entry_len * entries.len() as u64 + if big { 8 } else { 4 };
    let mut ext_off = ifd_off + ifd_len;
    let mut ifd = Vec::with_capacity(ifd_len as usize);
    let mut ext = Vec::new();
    let offset_bytes = |o: u64| -> Result<Vec<u8>> {
        if big {
            Ok(o.to_le_bytes().to_vec())
        } else {
            let o =
                u32::try_from(o).map_err(|_| OutputError::write(path, "classic TIFF offset overflow: use BigTIFF"))?;
            Ok(o.to_le_bytes().to_vec())
        }
    };
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
            ifd.extend_from_slice(&offset_bytes(ext_off)?);
            ext.extend_from_slice(&e.bytes);
            ext_off += e.bytes.len() as u64;
            if e.bytes.len() % 2 == 1 {
                ext.push(0);
                ext_off += 1;
            }
        }
    }
    ifd.extend_from_slice(&offset_bytes(next)?);
    ifd.extend_from_slice(&ext);
    Ok(ifd)
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
    let mut offsets_tab = Vec::with_capacity(n_strips);
    let mut counts = Vec::with_capacity(n_strips);
    for s in 0..n_strips {
        let rows = rows_per_strip.min(h - s * rows_per_strip) as u64;
        offsets_tab.push(header_len + s as u64 * rows_per_strip as u64 * row_bytes);
        counts.push(rows * row_bytes);
    }

    let mut entries = float_layout_entries(w, h, nb);
    entries.push(offsets(273, &offsets_tab, big));
    entries.push(longs(278, &[rows_per_strip as u32]));
    entries.push(offsets(279, &counts, big));
    entries.extend(geo_entries(&img.bands, opts)?);

    // IFD after the pixel data, then the out-of-line values.
    let ifd_off = header_len + data_bytes + (data_bytes & 1);
    let ifd = encode_ifd(entries, ifd_off, 0, big, path)?;
    if !big && ifd_off + ifd.len() as u64 > u32::MAX as u64 {
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
        f.write_all(&ifd)
    })?)
}
