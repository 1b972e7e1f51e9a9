//! LAS 1.4 writer and reader on the `las` crate, point data record format 8 (xyz, GPS time, RGB, NIR).
//!
//! Writer mapping (spec/multispectral.md §5.3):
//! - **RGB** = the bands nearest 660/555/450 nm and **NIR** = the band nearest 840 nm (within 30 nm), each stored
//!   as `u16 = round(clamp(reflectance, 0, 1) · 65535)`, i.e. reflectance = value / 65535 (precision 1.5e-5;
//!   reflectance above 1 saturates). When the three visible bands are not all present, RGB holds the display
//!   colour (`PointCloud::display_rgb` × 257); a missing NIR band leaves NIR 0.
//! - Every band not in an RGB/NIR slot (all bands with [`LasOptions::all_bands_as_extra_bytes`]) goes into
//!   **Extra Bytes** as f32, described by a `LASF_Spec` record-4 VLR of 192-byte descriptors packed here
//!   (data type 9 = float; name = the PLY property name, e.g. `refl_720`; description "RedEdge1 720nm").
//! - Normals, when the cloud has them, are three more f32 Extra Bytes named `NormalX`, `NormalY`, `NormalZ`
//!   (the names PDAL and CloudCompare use for normals in Extra Bytes); [`read_las`] reads them back.
//! - Attributes ([`super::ScalarField`]) follow as one f32 Extra Bytes each (data type 9), named after the
//!   attribute, with the first 31 bytes of its description (CloudCompare shows them as scalar fields).
//! - A VLR `msnerf`/1 holds the band list as JSON (name, centre, FWHM, and where each band is stored) and the
//!   attributes' names and full descriptions, so [`read_las`] restores the bands in their original order.
//! - Coordinates: `scale` (default 1 mm) and an `offset` (default: each axis' minimum rounded down to a
//!   multiple of 1000 m), so UTM-sized coordinates fit the i32 records at millimetre resolution; a cloud that
//!   does not fit is an error naming the axis.
//! - An OGC WKT CRS can be attached (`LASF_Projection`/2112, WKT bit set).
//!
//! Reading, every Extra Bytes field (any numeric type, scale/offset applied) that is not a band or a normal is an
//! attribute, in descriptor order (its name made valid and unique when it is not, as in the PLY reader). In a
//! foreign LAS (no msnerf VLR) the bands are the Extra Bytes named `refl_*` (centre parsed from `refl_<nm>`) or
//! `band_*`, and `rgb` is its colour (high byte, or the value itself when every colour fits 8 bits).

use std::io::BufWriter;
use std::path::Path;

use las::{point::Format, Builder, Color, Point, Reader, Transform, Vector, Vlr, Writer};
use serde::{Deserialize, Serialize};

use super::ply::band_property_names;
use super::{attribute_name_from, PointCloud, ScalarField};
use crate::output::image::{band, band_description, nearest_band};
use crate::output::raster::preview::{Stretch, COMPOSITE_TOLERANCE_NM, NATURAL_COLOUR_NM};
use crate::output::{atomic::AtomicFile, Band, OutputError, Result};

pub const REFLECTANCE_U16_SCALE: f64 = 65535.0;
pub const NIR_NM: f64 = 840.0;
/// Extra Bytes names of the normal components.
pub const NORMAL_NAMES: [&str; 3] = ["NormalX", "NormalY", "NormalZ"];
const MSNERF_USER_ID: &str = "msnerf";
const MSNERF_RECORD_ID: u16 = 1;

/// LAS writer options.
#[derive(Debug, Clone, PartialEq)]
pub struct LasOptions {
    /// Coordinate resolution per axis (default 0.001 = 1 mm).
    pub scale: [f64; 3],
    /// Coordinate offset; `None` = each axis' minimum rounded down to a multiple of 1000.
    pub offset: Option<[f64; 3]>,
    /// Also write the bands held in RGB/NIR as f32 extra bytes (exact values for every band).
    pub all_bands_as_extra_bytes: bool,
    /// OGC WKT of the CRS.
    pub wkt: Option<String>,
    /// Stretch of the display colours (used when RGB cannot come from the bands).
    pub stretch: Stretch,
}

impl Default for LasOptions {
    fn default() -> Self {
        LasOptions {
            scale: [0.001; 3],
            offset: None,
            all_bands_as_extra_bytes: false,
            wkt: None,
            stretch: Stretch::default(),
        }
    }
}

/// One Extra Bytes descriptor (the fields this crate uses).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraBytesDescriptor {
    pub data_type: u8,
    pub options: u8,
    pub name: String,
    pub scale: f64,
    pub offset: f64,
    pub description: String,
}

impl ExtraBytesDescriptor {
    /// A plain f32 field.
    pub fn f32(name: &str, description: &str) -> Self {
        ExtraBytesDescriptor {
            data_type: 9,
            options: 0,
            name: name.into(),
            scale: 1.0,
            offset: 0.0,
            description: description.into(),
        }
    }

    /// Packs the 192-byte record of the LAS 1.4 spec.
    pub fn pack(&self) -> [u8; 192] {
        let mut r = [0u8; 192];
        r[2] = self.data_type;
        r[3] = self.options;
        // At most 31 bytes (a NUL stays), cut at a character boundary.
        let put_str = |r: &mut [u8; 192], at: usize, s: &str| {
            let b = truncate_utf8(s, 31).as_bytes();
            r[at..at + b.len()].copy_from_slice(b);
        };
        put_str(&mut r, 4, &self.name);
        r[112..120].copy_from_slice(&self.scale.to_le_bytes());
        r[136..144].copy_from_slice(&self.offset.to_le_bytes());
        put_str(&mut r, 160, &self.description);
        r
    }

    /// Parses a 192-byte record.
    pub fn unpack(r: &[u8]) -> ExtraBytesDescriptor {
        let s = |b: &[u8]| String::from_utf8_lossy(b).trim_end_matches('\0').to_string();
        let f = |at: usize| f64::from_le_bytes(r[at..at + 8].try_into().expect("8 bytes"));
        ExtraBytesDescriptor {
            data_type: r[2],
            options: r[3],
            name: s(&r[4..36]),
            scale: f(112),
            offset: f(136),
            description: s(&r[160..192]),
        }
    }

    /// Bytes per value (type 0: `options` holds the size; 11-30: the deprecated 2- and 3-element arrays).
    pub fn size(&self) -> usize {
        match self.data_type {
            0 => self.options as usize,
            1 | 2 => 1,
            3 | 4 => 2,
            5 | 6 | 9 => 4,
            7 | 8 | 10 => 8,
            t @ 11..=30 => {
                let base = ExtraBytesDescriptor { data_type: (t - 1) % 10 + 1, ..self.clone() }.size();
                base * if t <= 20 { 2 } else { 3 }
            }
            _ => 0,
        }
    }

    fn decode(&self, b: &[u8]) -> f64 {
        let v = match self.data_type {
            1 => b[0] as f64,
            2 => b[0] as i8 as f64,
            3 => u16::from_le_bytes([b[0], b[1]]) as f64,
            4 => i16::from_le_bytes([b[0], b[1]]) as f64,
            5 => u32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            6 => i32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            7 => u64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as f64,
            8 => i64::from_le_bytes(b[..8].try_into().expect("8 bytes")) as f64,
            9 => f32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            10 => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")),
            _ => return f64::NAN,
        };
        // Only when their option bits are set, so unscaled values (-0.0 included) come back bit for bit.
        let v = if self.options & 8 != 0 { v * self.scale } else { v };
        if self.options & 16 != 0 {
            v + self.offset
        } else {
            v
        }
    }
}

/// The longest prefix of `s` of at most `max` bytes that ends at a character boundary.
fn truncate_utf8(s: &str, max: usize) -> &str {
    let mut n = s.len().min(max);
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    &s[..n]
}

#[derive(Serialize, Deserialize)]
struct AttributeRecord {
    /// The Extra Bytes name.
    name: String,
    /// The whole description (the descriptor holds 31 bytes of it).
    description: String,
}

#[derive(Serialize, Deserialize)]
struct BandRecord {
    name: String,
    center_nm: Option<f64>,
    fwhm_nm: Option<f64>,
    /// "red", "green", "blue", "nir" or "extra:<extra bytes name>".
    stored_as: String,
}

#[derive(Serialize, Deserialize)]
struct BandVlr {
    reflectance_u16_scale: f64,
    bands: Vec<BandRecord>,
    /// Absent in files from before attributes existed.
    #[serde(default)]
    attributes: Vec<AttributeRecord>,
}

fn to_u16(v: f32) -> u16 {
    if v.is_nan() {
        0
    } else {
        ((v as f64).clamp(0.0, 1.0) * REFLECTANCE_U16_SCALE).round() as u16
    }
}

/// Writes `cloud` as LAS 1.4 PDRF 8 (atomically).
pub fn write_las(path: &Path, cloud: &PointCloud, opts: &LasOptions) -> Result<()> {
    cloud.validate()?;
    let nb = cloud.n_bands();
    let find = |nm: f64| nearest_band(&cloud.bands, nm, COMPOSITE_TOLERANCE_NM, "las").ok();
    let rgb_bands: Option<Vec<usize>> = NATURAL_COLOUR_NM.iter().map(|&nm| find(nm)).collect();
    let rgb_bands = rgb_bands.filter(|v| v[0] != v[1] && v[1] != v[2] && v[0] != v[2]);
    let nir_band = find(NIR_NM).filter(|b| rgb_bands.as_ref().is_none_or(|v| !v.contains(b)));
    let names = band_property_names(&cloud.bands);
    let mut slot: Vec<String> = vec![String::new(); nb];
    if let Some(v) = &rgb_bands {
        for (c, &b) in ["red", "green", "blue"].iter().zip(v) {
            slot[b] = c.to_string();
        }
    }
    if let Some(b) = nir_band {
        slot[b] = "nir".into();
    }
    let extra: Vec<usize> = (0..nb).filter(|&b| slot[b].is_empty() || opts.all_bands_as_extra_bytes).collect();
    for &b in &extra {
        slot[b] =
            if slot[b].is_empty() { format!("extra:{}", names[b]) } else { format!("{}+extra:{}", slot[b], names[b]) };
    }

    // Header.
    let mut builder = Builder::from((1, 4));
    let mut format = Format::new(8).map_err(|e| OutputError::write(path, e))?;
    let n_normals = if cloud.normals.is_some() { 3 } else { 0 };
    let attrs = &cloud.attributes;
    let n_fields = extra.len() + n_normals + attrs.len();
    format.extra_bytes = u16::try_from(n_fields * 4).map_err(|_| {
        OutputError::invalid(
            "bands",
            format!(
                "{} extra-bytes bands, {n_normals} normal components and {} attributes are too many for LAS",
                extra.len(),
                attrs.len()
            ),
        )
    })?;
    builder.point_format = format;
    builder.generating_software = "msnerf".into();
    builder.system_identifier = "msnerf outputs".into();
    let offset = match opts.offset {
        Some(o) => o,
        None => {
            let mut lo = [f64::INFINITY; 3];
            cloud.positions.iter().for_each(|p| (0..3).for_each(|a| lo[a] = lo[a].min(p[a])));
            lo.map(|v| if v.is_finite() { (v / 1000.0).floor() * 1000.0 } else { 0.0 })
        }
    };
    for a in 0..3 {
        if opts.scale[a].is_nan() || opts.scale[a] <= 0.0 {
            return Err(OutputError::invalid(
                "las scale",
                format!("axis {a}: must be positive, got {}", opts.scale[a]),
            ));
        }
        let axis = ["x", "y", "z"][a];
        for p in &cloud.positions {
            let q = ((p[a] - offset[a]) / opts.scale[a]).round();
            if q < i32::MIN as f64 || q > i32::MAX as f64 {
                return Err(OutputError::invalid(
                    "las scale/offset",
                    format!(
                        "{axis} = {} does not fit i32 records with scale {} and offset {}",
                        p[a], opts.scale[a], offset[a]
                    ),
                ));
            }
        }
    }
    builder.transforms = Vector {
        x: Transform { scale: opts.scale[0], offset: offset[0] },
        y: Transform { scale: opts.scale[1], offset: offset[1] },
        z: Transform { scale: opts.scale[2], offset: offset[2] },
    };
    if n_fields > 0 {
        let mut data = Vec::with_capacity(192 * n_fields);
        for &b in &extra {
            let d = ExtraBytesDescriptor::f32(&names[b], &band_description(&cloud.bands[b]));
            data.extend_from_slice(&d.pack());
        }
        if n_normals > 0 {
            for (name, axis) in NORMAL_NAMES.iter().zip(["x", "y", "z"]) {
                let d = ExtraBytesDescriptor::f32(name, &format!("unit surface normal, {axis}"));
                data.extend_from_slice(&d.pack());
            }
        }
        for a in attrs {
            data.extend_from_slice(&ExtraBytesDescriptor::f32(&a.name, &a.description).pack());
        }
        builder.vlrs.push(Vlr { user_id: "LASF_Spec".into(), record_id: 4, description: "Extra Bytes".into(), data });
    }
    let band_vlr = BandVlr {
        reflectance_u16_scale: REFLECTANCE_U16_SCALE,
        bands: cloud
            .bands
            .iter()
            .zip(&slot)
            .map(|(b, s)| BandRecord {
                name: b.name.clone(),
                center_nm: b.center_nm,
                fwhm_nm: b.fwhm_nm,
                stored_as: s.clone(),
            })
            .collect(),
        attributes: attrs
            .iter()
            .map(|a| AttributeRecord { name: a.name.clone(), description: a.description.clone() })
            .collect(),
    };
    builder.vlrs.push(Vlr {
        user_id: MSNERF_USER_ID.into(),
        record_id: MSNERF_RECORD_ID,
        description: "band metadata (JSON)".into(),
        data: serde_json::to_vec(&band_vlr).expect("band list serialises"),
    });
    if let Some(wkt) = &opts.wkt {
        let mut data = wkt.as_bytes().to_vec();
        data.push(0);
        builder.vlrs.push(Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 2112,
            description: "OGC WKT".into(),
            data,
        });
        builder.has_wkt_crs = true;
    }
    let header = builder.into_header().map_err(|e| OutputError::write(path, e))?;

    let display = if rgb_bands.is_none() { Some(cloud.display_rgb(opts.stretch)) } else { None };
    let (atomic, file) = AtomicFile::create(path)?;
    let mut writer =
        Writer::new(BufWriter::with_capacity(1 << 20, file), header).map_err(|e| OutputError::write(path, e))?;
    for i in 0..cloud.len() {
        let v = cloud.point_values(i);
        let color = match (&rgb_bands, &display) {
            (Some(idx), _) => Color { red: to_u16(v[idx[0]]), green: to_u16(v[idx[1]]), blue: to_u16(v[idx[2]]) },
            (None, Some(d)) => {
                Color { red: d[i][0] as u16 * 257, green: d[i][1] as u16 * 257, blue: d[i][2] as u16 * 257 }
            }
            (None, None) => Color::default(),
        };
        let p = cloud.positions[i];
        let point = Point {
            x: p[0],
            y: p[1],
            z: p[2],
            gps_time: Some(0.0),
            color: Some(color),
            nir: Some(nir_band.map(|b| to_u16(v[b])).unwrap_or(0)),
            extra_bytes: extra
                .iter()
                .map(|&b| v[b])
                .chain(cloud.normals.as_ref().map(|n| n[i]).into_iter().flatten())
                .chain(attrs.iter().map(|a| a.values[i]))
                .flat_map(f32::to_le_bytes)
                .collect(),
            ..Default::default()
        };
        writer.write_point(point).map_err(|e| OutputError::write(path, e))?;
    }
    let inner = writer.into_inner().map_err(|e| OutputError::write(path, e))?;
    let file = inner.into_inner().map_err(|e| OutputError::write(path, e.error()))?;
    file.sync_all().map_err(|e| OutputError::write(path, e))?;
    drop(file);
    Ok(atomic.commit()?)
}

/// Reads a LAS file (bands from the msnerf band VLR when present, otherwise from the Extra Bytes named `refl_*` or
/// `band_*`; the other Extra Bytes except normals are attributes).
pub fn read_las(path: &Path) -> Result<PointCloud> {
    let mut reader = Reader::from_path(path).map_err(|e| OutputError::read(path, e))?;
    let header = reader.header().clone();
    // The header's point count must fit in the file: a damaged count would otherwise allocate it up front.
    let file_len = std::fs::metadata(path).map_err(|e| OutputError::read(path, e))?.len();
    let record = header.point_format().len() as u64;
    if !header.point_format().is_compressed && header.number_of_points().saturating_mul(record) > file_len {
        return Err(OutputError::read(
            path,
            format!(
                "the header counts {} points of {record} bytes, more than the file's {file_len} bytes hold",
                header.number_of_points()
            ),
        ));
    }
    let mut descriptors = Vec::new();
    let mut band_vlr: Option<BandVlr> = None;
    for vlr in header.all_vlrs() {
        if vlr.user_id == "LASF_Spec" && vlr.record_id == 4 {
            descriptors = vlr.data.chunks_exact(192).map(ExtraBytesDescriptor::unpack).collect();
        } else if vlr.user_id == MSNERF_USER_ID && vlr.record_id == MSNERF_RECORD_ID {
            band_vlr = serde_json::from_slice(&vlr.data).ok();
        }
    }
    // Byte offset of each descriptor inside a point's extra bytes.
    let mut at = Vec::with_capacity(descriptors.len());
    let mut off = 0usize;
    for d in &descriptors {
        at.push(off);
        off += d.size();
    }
    let n_extra = header.point_format().extra_bytes as usize;
    if off > n_extra {
        return Err(OutputError::read(
            path,
            format!("extra bytes descriptors need {off} bytes per point, records hold {n_extra}"),
        ));
    }
    let extra_by_name = |name: &str| descriptors.iter().position(|d| d.name == name);
    // Scalar fields this reader decodes (not undocumented bytes, not the deprecated arrays).
    let readable = |d: &ExtraBytesDescriptor| (1..=10).contains(&d.data_type);
    let normal_idx: Option<Vec<usize>> = NORMAL_NAMES.iter().map(|&nm| extra_by_name(nm)).collect();

    enum Source {
        Red,
        Green,
        Blue,
        Nir,
        Extra(usize),
    }
    let mut bands: Vec<Band> = Vec::new();
    let mut sources: Vec<Source> = Vec::new();
    match &band_vlr {
        Some(bv) => {
            for r in &bv.bands {
                let src = if let Some(e) = r.stored_as.split("extra:").nth(1).and_then(extra_by_name) {
                    Source::Extra(e)
                } else {
                    match r.stored_as.as_str() {
                        "red" => Source::Red,
                        "green" => Source::Green,
                        "blue" => Source::Blue,
                        "nir" => Source::Nir,
                        s => return Err(OutputError::read(path, format!("band `{}` stored as unknown `{s}`", r.name))),
                    }
                };
                bands.push(Band {
                    name: r.name.clone(),
                    center_nm: r.center_nm,
                    fwhm_nm: r.fwhm_nm,
                    pixel_scale: None,
                    black_level: None,
                });
                sources.push(src);
            }
        }
        None => {
            for (i, d) in descriptors.iter().enumerate() {
                if !readable(d) || !(d.name.starts_with("refl_") || d.name.starts_with("band_")) {
                    continue;
                }
                let centre = d.name.strip_prefix("refl_").and_then(|s| s.parse::<f64>().ok());
                bands.push(band(&d.name, centre, None));
                sources.push(Source::Extra(i));
            }
        }
    }
    // Attributes: the remaining Extra Bytes, in descriptor order.
    let mut taken = band_property_names(&bands);
    let mut attr_idx = Vec::new();
    let mut attributes = Vec::new();
    for (i, d) in descriptors.iter().enumerate() {
        let is_normal = normal_idx.as_ref().is_some_and(|v| v.contains(&i));
        if !readable(d) || is_normal || sources.iter().any(|s| matches!(s, Source::Extra(e) if *e == i)) {
            continue;
        }
        let name = attribute_name_from(&d.name, &taken);
        taken.push(name.clone());
        let description = band_vlr
            .as_ref()
            .and_then(|bv| bv.attributes.iter().find(|a| a.name == d.name))
            .map_or_else(|| d.description.clone(), |a| a.description.clone());
        attr_idx.push(i);
        attributes.push(ScalarField { name, values: Vec::new(), description });
    }
    let scale = band_vlr.as_ref().map(|b| b.reflectance_u16_scale).unwrap_or(REFLECTANCE_U16_SCALE);
    let data = reader.read_all().map_err(|e| OutputError::read(path, e))?;
    let n = data.len();
    let mut positions = Vec::with_capacity(n);
    let mut values = Vec::with_capacity(n * bands.len());
    let mut colours = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(if normal_idx.is_some() { n } else { 0 });
    let has_color = header.point_format().has_color;
    for p in data.points() {
        let p = p.map_err(|e| OutputError::read(path, e))?;
        positions.push([p.x, p.y, p.z]);
        let c = p.color.unwrap_or_default();
        colours.push([c.red, c.green, c.blue]);
        for s in &sources {
            let v = match s {
                Source::Red => c.red as f64 / scale,
                Source::Green => c.green as f64 / scale,
                Source::Blue => c.blue as f64 / scale,
                Source::Nir => p.nir.unwrap_or(0) as f64 / scale,
                Source::Extra(e) => {
                    let d = &descriptors[*e];
                    match p.extra_bytes.get(at[*e]..at[*e] + d.size()) {
                        Some(b) => d.decode(b),
                        None => f64::NAN,
                    }
                }
            };
            values.push(v as f32);
        }
        if let Some(idx) = &normal_idx {
            normals.push([0, 1, 2].map(|k| {
                let (d, a) = (&descriptors[idx[k]], at[idx[k]]);
                p.extra_bytes.get(a..a + d.size()).map_or(f32::NAN, |b| d.decode(b) as f32)
            }));
        }
        for (attr, &e) in attributes.iter_mut().zip(&attr_idx) {
            let (d, a) = (&descriptors[e], at[e]);
            attr.values.push(p.extra_bytes.get(a..a + d.size()).map_or(f32::NAN, |b| d.decode(b) as f32));
        }
    }
    let eight_bit = colours.iter().all(|c| c.iter().all(|&v| v <= 255));
    let rgb = has_color
        .then(|| colours.iter().map(|c| c.map(|v| if eight_bit { v as u8 } else { (v >> 8) as u8 })).collect());
    let normals = normal_idx.map(|_| normals);
    let cloud = PointCloud { positions, bands, values, normals, rgb, attributes };
    cloud.validate().map_err(|e| OutputError::read(path, e))?;
    Ok(cloud)
}
