//! Metadata of one single-band rig file: the EXIF/TIFF tags (kamadak-exif reads IFD0, the Exif and GPS IFDs of
//! a TIFF container, and keeps private tags such as BlackLevel 50714 and XMP 700) and the XMP packet
//! ([`crate::data::xmp::XmpProps`]). Pixels are read separately ([`read_pixels`], the `tiff` crate), so grouping
//! a 1,000-capture folder reads headers only.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use exif::{Context, Exif, In, Tag, Value};

use super::error::RigError;
use crate::data::xmp::XmpProps;

/// GPS position (WGS84 degrees, metres above the ellipsoid or sea level as the file says).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GpsFix {
    pub latitude: f64,
    pub longitude: f64,
    pub altitude: Option<f64>,
}

/// What one file says about itself, before any vendor interpretation.
#[derive(Debug, Clone)]
pub struct FileMeta {
    pub path: PathBuf,
    pub width: u32,
    pub height: u32,
    pub bits_per_sample: u32,
    pub samples_per_pixel: u32,
    pub make: Option<String>,
    pub model: Option<String>,
    /// EXIF Software: the camera's firmware version.
    pub software: Option<String>,
    pub exposure_s: Option<f64>,
    pub iso: Option<f64>,
    pub black_level: Option<Vec<f64>>,
    pub focal_plane_x_res_per_mm: Option<f64>,
    /// EXIF FocalLength in millimetres.
    pub focal_length_mm: Option<f64>,
    pub datetime: Option<String>,
    /// False when the camera's clock was not set (a date before 2000: cameras without a GPS fix write 1970).
    pub clock_set: bool,
    pub gps: Option<GpsFix>,
    /// Why the file's GPS tags were not taken as a fix (they read 0 N 0 E: cameras write that without a fix).
    pub gps_rejected: Option<String>,
    pub xmp: XmpProps,
}

fn number(v: &Value, i: usize) -> Option<f64> {
    let x = match v {
        Value::Byte(a) => *a.get(i)? as f64,
        Value::Short(a) => *a.get(i)? as f64,
        Value::Long(a) => *a.get(i)? as f64,
        Value::SShort(a) => *a.get(i)? as f64,
        Value::SLong(a) => *a.get(i)? as f64,
        Value::Rational(a) => a.get(i)?.to_f64(),
        Value::SRational(a) => a.get(i)?.to_f64(),
        Value::Float(a) => *a.get(i)? as f64,
        Value::Double(a) => *a.get(i)?,
        _ => return None,
    };
    x.is_finite().then_some(x)
}

fn value_len(v: &Value) -> usize {
    match v {
        Value::Byte(a) => a.len(),
        Value::Short(a) => a.len(),
        Value::Long(a) => a.len(),
        Value::SShort(a) => a.len(),
        Value::SLong(a) => a.len(),
        Value::Rational(a) => a.len(),
        Value::SRational(a) => a.len(),
        Value::Float(a) => a.len(),
        Value::Double(a) => a.len(),
        _ => 0,
    }
}

fn numbers(v: &Value) -> Vec<f64> {
    (0..value_len(v)).filter_map(|i| number(v, i)).collect()
}

fn ascii(exif: &Exif, tag: Tag) -> Option<String> {
    match &exif.get_field(tag, In::PRIMARY)?.value {
        Value::Ascii(parts) => parts
            .first()
            .map(|b| String::from_utf8_lossy(b).trim_end_matches('\0').trim().to_string())
            .filter(|s| !s.is_empty()),
        _ => None,
    }
}

fn num(exif: &Exif, tag: Tag) -> Option<f64> {
    number(&exif.get_field(tag, In::PRIMARY)?.value, 0)
}

fn dms(exif: &Exif, tag: Tag, reference: Tag, negative: u8) -> Option<f64> {
    let v = numbers(&exif.get_field(tag, In::PRIMARY)?.value);
    if v.len() < 3 {
        return None;
    }
    let deg = v[0] + v[1] / 60.0 + v[2] / 3600.0;
    let sign = match exif.get_field(reference, In::PRIMARY).map(|f| &f.value) {
        Some(Value::Ascii(p)) if p.first().and_then(|b| b.first()) == Some(&negative) => -1.0,
        _ => 1.0,
    };
    Some(sign * deg)
}

/// The EXIF tag number of an XMP packet and of DNG's BlackLevel.
pub const TAG_XMP: u16 = 700;
pub const TAG_BLACK_LEVEL: u16 = 50714;

/// Reads the tags of `path` (no pixels).
pub fn read_meta(path: &Path) -> Result<FileMeta, RigError> {
    let file = File::open(path).map_err(RigError::io(path))?;
    let exif = exif::Reader::new()
        .continue_on_error(true)
        .read_from_container(&mut BufReader::new(file))
        .or_else(|e| e.distill_partial_result(|_| {}))
        .map_err(|e| RigError::Tiff { path: path.into(), reason: e.to_string() })?;
    let field = |t: Tag| exif.get_field(t, In::PRIMARY);
    let width = field(Tag::ImageWidth).and_then(|f| f.value.get_uint(0));
    let height = field(Tag::ImageLength).and_then(|f| f.value.get_uint(0));
    let (Some(width), Some(height)) = (width, height) else {
        return Err(RigError::missing(path, "ImageWidth/ImageLength", "not a TIFF image"));
    };
    let bits_per_sample = field(Tag::BitsPerSample).and_then(|f| f.value.get_uint(0)).unwrap_or(1);
    let samples_per_pixel = field(Tag::SamplesPerPixel).and_then(|f| f.value.get_uint(0)).unwrap_or(1);
    let xmp = field(Tag(Context::Tiff, TAG_XMP))
        .and_then(|f| match &f.value {
            Value::Byte(b) | Value::Undefined(b, _) => XmpProps::parse(b),
            Value::Ascii(parts) => XmpProps::parse(&parts.concat()),
            _ => None,
        })
        .unwrap_or_default();
    let black_level = field(Tag(Context::Tiff, TAG_BLACK_LEVEL)).map(|f| numbers(&f.value)).filter(|v| !v.is_empty());
    let iso = num(&exif, Tag::PhotographicSensitivity).or_else(|| num(&exif, Tag::ISOSpeed));
    let mut gps_rejected = None;
    let gps = match (
        dms(&exif, Tag::GPSLatitude, Tag::GPSLatitudeRef, b'S'),
        dms(&exif, Tag::GPSLongitude, Tag::GPSLongitudeRef, b'W'),
    ) {
        (Some(latitude), Some(longitude)) if latitude.abs() < 1e-7 && longitude.abs() < 1e-7 => {
            gps_rejected = Some("its GPS tags read 0 N 0 E, what cameras write without a fix".to_string());
            None
        }
        (Some(latitude), Some(_)) if latitude.abs() > 90.0 => {
            gps_rejected = Some(format!("its GPS latitude {latitude} is not on Earth"));
            None
        }
        (Some(latitude), Some(longitude)) => {
            let below =
                matches!(field(Tag::GPSAltitudeRef).map(|f| &f.value), Some(Value::Byte(b)) if b.first() == Some(&1));
            let altitude = num(&exif, Tag::GPSAltitude).map(|a| if below { -a } else { a });
            Some(GpsFix { latitude, longitude, altitude })
        }
        _ => None,
    };
    let mut datetime = ascii(&exif, Tag::DateTimeOriginal).or_else(|| ascii(&exif, Tag::DateTime));
    if let (Some(dt), Some(sub)) = (datetime.as_mut(), ascii(&exif, Tag::SubSecTimeOriginal)) {
        dt.push('.');
        dt.push_str(&sub);
    }
    let clock_set =
        datetime.as_deref().and_then(|d| d.get(..4)).and_then(|y| y.parse::<u32>().ok()).is_some_and(|y| y >= 2000);
    let fp_res = num(&exif, Tag::FocalPlaneXResolution).map(|r| {
        // FocalPlaneResolutionUnit: 2 inch, 3 cm, 4 mm (MicaSense writes 4).
        match field(Tag::FocalPlaneResolutionUnit).and_then(|f| f.value.get_uint(0)) {
            Some(2) => r / 25.4,
            Some(3) => r / 10.0,
            _ => r,
        }
    });
    Ok(FileMeta {
        path: path.to_path_buf(),
        width,
        height,
        bits_per_sample,
        samples_per_pixel,
        make: ascii(&exif, Tag::Make),
        model: ascii(&exif, Tag::Model),
        software: ascii(&exif, Tag::Software),
        exposure_s: num(&exif, Tag::ExposureTime),
        iso,
        black_level,
        focal_plane_x_res_per_mm: fp_res,
        focal_length_mm: num(&exif, Tag::FocalLength).filter(|f| *f > 0.0),
        datetime,
        clock_set,
        gps,
        gps_rejected,
        xmp,
    })
}

/// Reads the pixels of a single-band 8- or 16-bit file as f64 DN, row-major.
pub fn read_pixels(meta: &FileMeta) -> Result<Vec<f64>, RigError> {
    use tiff::decoder::{Decoder, DecodingResult};
    let path = &meta.path;
    let fail = |reason: String| RigError::Tiff { path: path.clone(), reason };
    let file = File::open(path).map_err(RigError::io(path))?;
    let mut dec = Decoder::new(BufReader::new(file)).map_err(|e| fail(e.to_string()))?;
    let (w, h) = dec.dimensions().map_err(|e| fail(e.to_string()))?;
    if (w, h) != (meta.width, meta.height) {
        return Err(fail(format!("image is {w}x{h} but its tags say {}x{}", meta.width, meta.height)));
    }
    let px: Vec<f64> = match dec.read_image().map_err(|e| fail(e.to_string()))? {
        DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::U8(v) => v.into_iter().map(f64::from).collect(),
        _ => return Err(fail("raw rig files must be 8- or 16-bit unsigned, one sample per pixel".into())),
    };
    if px.len() != (w as usize) * (h as usize) {
        return Err(fail(format!("{} samples for {w}x{h} pixels: not a single-band image", px.len())));
    }
    Ok(px)
}
