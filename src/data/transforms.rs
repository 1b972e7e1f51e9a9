//! Parses `transforms.json` (nerfstudio format plus `bands`, `band_files`, `pixel_scale`, `black_level`) into
//! plain values, collecting every error with its key and frame. Unknown keys are ignored.
//!
//! Walks a `serde_json::Value` by hand instead of deriving `Deserialize`, so that a wrong value names its key
//! and frame and one bad frame does not hide the problems of the others.

use std::path::{Path, PathBuf};

use serde_json::{Map, Value};

use super::camera::{Camera, CameraModel, Distortion};
use super::error::{DataError, FrameRef};
use super::pose::Mat4;
use super::split::{Split, SplitLists};

/// A band as declared in `bands` (or found in XMP, or the RGB default).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Band {
    pub name: String,
    /// Centre wavelength in nm (`None` only for the RGB default of plain nerfstudio datasets).
    pub center_nm: Option<f64>,
    pub fwhm_nm: Option<f64>,
    /// Per-band `pixel_scale` (overrides the top-level one).
    pub pixel_scale: Option<f64>,
    /// Per-band `black_level` (overrides the top-level one and the file's BlackLevel tag).
    pub black_level: Option<f64>,
}

/// One frame as written (before sorting and splitting).
#[derive(Debug, Clone)]
pub struct RawFrame {
    pub index: usize,
    /// `file_path` or the first of `band_files`, as written (sort and split key).
    pub name: String,
    pub file_path: Option<PathBuf>,
    pub band_files: Option<Vec<PathBuf>>,
    pub mask_path: Option<PathBuf>,
    pub depth_path: Option<PathBuf>,
    pub c2w: Mat4,
    pub camera: Camera,
    pub split: Option<Split>,
}

/// Everything `transforms.json` says.
#[derive(Debug, Clone)]
pub struct RawTransforms {
    pub frames: Vec<RawFrame>,
    pub bands: Option<Vec<Band>>,
    pub pixel_scale: Option<f64>,
    pub black_level: Option<f64>,
    pub depth_unit_scale_factor: f64,
    pub depth_is_z: bool,
    pub lists: SplitLists,
    /// `sparse_points_path`, resolved against the file's folder ([`super::sparse_points`]).
    pub sparse_points: Option<PathBuf>,
    /// nerfstudio's `applied_transform` (poses and points as written are this times the original ones).
    pub applied_transform: Option<Mat4>,
    /// `crs`: the projected CRS the poses' world frame is in (easting, northing, height in metres).
    pub crs: Option<crate::geo::Crs>,
    /// `rig_cameras`: per-band cameras of a multi-camera rig ([`super::rig_cameras`]), band names not yet resolved.
    pub rig_cameras: Option<super::rig_cameras::RawRig>,
}

pub(super) struct Ctx<'a> {
    pub(super) path: &'a Path,
    pub(super) errors: Vec<DataError>,
}

impl Ctx<'_> {
    pub(super) fn invalid(&mut self, key: &str, frame: Option<&FrameRef>, reason: impl Into<String>) {
        self.errors.push(DataError::InvalidValue {
            path: self.path.to_path_buf(),
            key: key.into(),
            frame: frame.cloned(),
            reason: reason.into(),
        });
    }
    pub(super) fn missing(&mut self, key: &str, frame: Option<&FrameRef>) {
        self.errors.push(DataError::MissingKey {
            path: self.path.to_path_buf(),
            key: key.into(),
            frame: frame.cloned(),
        });
    }
    pub(super) fn num(&mut self, obj: &Map<String, Value>, key: &str, frame: Option<&FrameRef>) -> Option<f64> {
        match obj.get(key) {
            None | Some(Value::Null) => None,
            Some(Value::Number(n)) => n.as_f64().filter(|v| v.is_finite()).or_else(|| {
                self.invalid(key, frame, "not a finite number");
                None
            }),
            Some(_) => {
                self.invalid(key, frame, "expected a number");
                None
            }
        }
    }
    pub(super) fn string(&mut self, obj: &Map<String, Value>, key: &str, frame: Option<&FrameRef>) -> Option<String> {
        match obj.get(key) {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
            Some(_) => {
                self.invalid(key, frame, "expected a non-empty string");
                None
            }
        }
    }
    pub(super) fn string_list(
        &mut self,
        obj: &Map<String, Value>,
        key: &str,
        frame: Option<&FrameRef>,
    ) -> Option<Vec<String>> {
        match obj.get(key) {
            None | Some(Value::Null) => None,
            Some(Value::Array(a)) => {
                let v: Option<Vec<String>> = a.iter().map(|x| x.as_str().map(str::to_string)).collect();
                if v.is_none() {
                    self.invalid(key, frame, "expected a list of strings");
                }
                v
            }
            Some(_) => {
                self.invalid(key, frame, "expected a list of strings");
                None
            }
        }
    }
}

const INTRINSIC_KEYS: [&str; 6] = ["fl_x", "fl_y", "cx", "cy", "w", "h"];
/// Plausible focal lengths, in multiples of the image's larger side: fields of view between 179.9° and 6e-5°.
pub const MIN_FOCAL_PER_PIXEL: f64 = 1e-3;
pub const MAX_FOCAL_PER_PIXEL: f64 = 1e6;

/// Why a positive focal length `f` (pixels) makes no usable camera for a `width` x `height` image: outside
/// [`MIN_FOCAL_PER_PIXEL`]..=[`MAX_FOCAL_PER_PIXEL`] times the larger side (rays that overflow, or all parallel: a
/// unit or typing mistake). `None` when it is plausible.
pub fn implausible_focal(f: f64, width: f64, height: f64) -> Option<String> {
    let size = width.max(height);
    if (size * MIN_FOCAL_PER_PIXEL..=size * MAX_FOCAL_PER_PIXEL).contains(&f) {
        return None;
    }
    let fov = (size / (2.0 * f)).atan().to_degrees() * 2.0;
    Some(format!(
        "focal length {f:e} pixels for a {width}x{height} image (field of view {fov:.4}°) is implausible: it must lie \
         between {MIN_FOCAL_PER_PIXEL} and {MAX_FOCAL_PER_PIXEL:e} times the image's larger side"
    ))
}

/// Parses the file at `path` (paths in it are resolved against its folder).
pub fn parse_transforms(path: &Path) -> Result<RawTransforms, DataError> {
    let root: Value = read_json(path, "transforms.json")?;
    parse_value(path, &root)
}

/// Reads and parses the JSON file at `path`; a missing or unreadable file names `key` (the key or file that
/// pointed to it), malformed JSON names the file.
pub(crate) fn read_json<T: serde::de::DeserializeOwned>(path: &Path, key: &str) -> Result<T, DataError> {
    let text = std::fs::read(path).map_err(|e| DataError::MissingFile {
        path: path.to_path_buf(),
        key: key.into(),
        frame: None,
        reason: e.to_string(),
    })?;
    serde_json::from_slice(&text).map_err(|e| DataError::Json { path: path.to_path_buf(), reason: e.to_string() })
}

/// Parses an already-read JSON value.
pub fn parse_value(path: &Path, root: &Value) -> Result<RawTransforms, DataError> {
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut cx = Ctx { path, errors: Vec::new() };
    let Some(top) = root.as_object() else {
        return Err(DataError::Json { path: path.to_path_buf(), reason: "top level is not an object".into() });
    };
    let pixel_scale = cx.num(top, "pixel_scale", None);
    let black_level = cx.num(top, "black_level", None);
    for (k, v) in [("pixel_scale", pixel_scale)] {
        if v.is_some_and(|v| v <= 0.0) {
            cx.invalid(k, None, "must be positive");
        }
    }
    let depth_unit_scale_factor = cx.num(top, "depth_unit_scale_factor", None).unwrap_or(1e-3);
    let depth_is_z = match cx.string(top, "depth_type", None).as_deref() {
        None | Some("z") => true,
        Some("ray_distance") => false,
        Some(o) => {
            cx.invalid("depth_type", None, format!("`{o}` is neither `z` nor `ray_distance`"));
            true
        }
    };
    let sparse_points = cx.string(top, "sparse_points_path", None).map(|p| dir.join(p));
    // nerfstudio's `ns-process-data` writes poses as `applied_transform * c2w` (an axis permutation of COLMAP's
    // frame); msnerf undoes it so its outputs land in COLMAP's (or the georeferenced) frame.
    let applied_transform =
        top.get("applied_transform").and_then(|v| rigid_matrix(&mut cx, v, "applied_transform", None));
    let crs = parse_crs(&mut cx, top);
    let bands = parse_bands(&mut cx, top);
    let rig_cameras = super::rig_cameras::parse(&mut cx, top);
    let lists = SplitLists {
        train: cx.string_list(top, "train_filenames", None),
        val: cx.string_list(top, "val_filenames", None),
        test: cx.string_list(top, "test_filenames", None),
    };
    let frames_v = match top.get("frames") {
        Some(Value::Array(a)) => a.clone(),
        Some(_) => {
            cx.invalid("frames", None, "expected a list");
            vec![]
        }
        None => {
            cx.missing("frames", None);
            vec![]
        }
    };
    if frames_v.is_empty() && top.get("frames").is_some_and(|f| f.is_array()) {
        cx.invalid("frames", None, "no frames");
    }
    let mut frames = Vec::new();
    for (i, fv) in frames_v.iter().enumerate() {
        let Some(f) = fv.as_object() else {
            cx.invalid("frames", Some(&FrameRef { index: i, name: String::new() }), "frame is not an object");
            continue;
        };
        if let Some(fr) = parse_frame(&mut cx, top, f, i, &dir) {
            frames.push(fr);
        }
    }
    if let Some(e) = DataError::from_list(cx.errors) {
        return Err(e);
    }
    Ok(RawTransforms {
        frames,
        bands,
        pixel_scale,
        black_level,
        depth_unit_scale_factor,
        depth_is_z,
        lists,
        sparse_points,
        applied_transform,
        crs,
        rig_cameras,
    })
}

/// `crs`: an EPSG code (`EPSG:32650`) or OGC WKT; it must be a projected CRS, since the world frame is metric.
fn parse_crs(cx: &mut Ctx, top: &Map<String, Value>) -> Option<crate::geo::Crs> {
    let text = cx.string(top, "crs", None)?;
    match crate::geo::Crs::parse(&text) {
        Ok(c) if c.kind == crate::geo::CrsKind::Projected => Some(c),
        Ok(c) => {
            cx.invalid(
                "crs",
                None,
                format!(
                    "{} is a {} CRS; poses need a projected CRS in metres (e.g. the flight's UTM zone, EPSG:326zz)",
                    c.describe(),
                    c.kind.name()
                ),
            );
            None
        }
        Err(e) => {
            cx.invalid("crs", None, e.to_string());
            None
        }
    }
}

fn parse_bands(cx: &mut Ctx, top: &Map<String, Value>) -> Option<Vec<Band>> {
    let list = match top.get("bands") {
        None | Some(Value::Null) => return None,
        Some(Value::Array(a)) => a,
        Some(_) => {
            cx.invalid("bands", None, "expected a list of {name, center_nm, fwhm_nm?}");
            return None;
        }
    };
    if list.is_empty() {
        cx.invalid("bands", None, "empty band list");
        return None;
    }
    let mut out = Vec::new();
    for (i, b) in list.iter().enumerate() {
        let key = format!("bands[{i}]");
        let Some(o) = b.as_object() else {
            cx.invalid(&key, None, "expected an object {name, center_nm, fwhm_nm?}");
            continue;
        };
        let Some(name) = cx.string(o, "name", None) else {
            cx.missing(&format!("{key}.name"), None);
            continue;
        };
        let center_nm = cx.num(o, "center_nm", None);
        if center_nm.is_none() {
            cx.missing(&format!("{key}.center_nm"), None);
        }
        let band = Band {
            name,
            center_nm,
            fwhm_nm: cx.num(o, "fwhm_nm", None),
            pixel_scale: cx.num(o, "pixel_scale", None),
            black_level: cx.num(o, "black_level", None),
        };
        if band.pixel_scale.is_some_and(|v| v <= 0.0) {
            cx.invalid(&format!("{key}.pixel_scale"), None, "must be positive");
        }
        if out.iter().any(|o: &Band| o.name.eq_ignore_ascii_case(&band.name)) {
            cx.invalid(&format!("{key}.name"), None, format!("duplicate band name `{}`", band.name));
        }
        out.push(band);
    }
    Some(out)
}

fn parse_frame(
    cx: &mut Ctx,
    top: &Map<String, Value>,
    f: &Map<String, Value>,
    index: usize,
    dir: &Path,
) -> Option<RawFrame> {
    let file_path = cx.string(f, "file_path", Some(&FrameRef { index, name: String::new() }));
    let fr0 = FrameRef { index, name: String::new() };
    let band_files = cx.string_list(f, "band_files", Some(&fr0));
    let name = file_path.clone().or_else(|| band_files.as_ref().and_then(|b| b.first().cloned())).unwrap_or_default();
    let fr = FrameRef { index, name: name.clone() };
    let before = cx.errors.len();
    match (&file_path, &band_files) {
        (None, None) => cx.missing("file_path", Some(&fr)),
        (Some(_), Some(_)) => cx.invalid("band_files", Some(&fr), "give either `file_path` or `band_files`, not both"),
        (None, Some(b)) if b.is_empty() => cx.invalid("band_files", Some(&fr), "empty list"),
        _ => {}
    }
    let c2w = parse_matrix(cx, f, &fr);
    // Intrinsics: the frame's value, else the top level's.
    let mut vals = [0.0f64; 6];
    for (k, key) in INTRINSIC_KEYS.iter().enumerate() {
        let v = if f.contains_key(*key) { cx.num(f, key, Some(&fr)) } else { cx.num(top, key, None) };
        vals[k] = match (v, *key) {
            (Some(v), _) => v,
            // SIMPLE_PINHOLE datasets sometimes carry only fl_x.
            (None, "fl_y") if f.contains_key("fl_x") || top.contains_key("fl_x") => f64::NAN,
            (None, _) => {
                cx.missing(key, Some(&fr));
                0.0
            }
        };
    }
    if vals[1].is_nan() {
        vals[1] = vals[0];
    }
    for (k, key) in ["fl_x", "fl_y"].iter().enumerate() {
        if vals[k] <= 0.0 && (f.contains_key(*key) || top.contains_key(*key)) {
            cx.errors.push(DataError::NonPositiveFocal {
                path: cx.path.to_path_buf(),
                key: key.to_string(),
                frame: Some(fr.clone()),
                value: vals[k],
            });
        } else if vals[k] > 0.0 && vals[4] >= 1.0 && vals[5] >= 1.0 {
            if let Some(why) = implausible_focal(vals[k], vals[4], vals[5]) {
                cx.invalid(key, Some(&fr), why);
            }
        }
    }
    for (k, key) in [(4, "w"), (5, "h")] {
        let bad = vals[k] < 1.0 || vals[k].fract() != 0.0 || vals[k] > 1e6;
        if bad && (f.contains_key(key) || top.contains_key(key)) {
            cx.invalid(key, Some(&fr), "image size must be a positive integer");
        }
    }
    let get = |cx: &mut Ctx, key: &str| -> f64 {
        if f.contains_key(key) {
            cx.num(f, key, Some(&fr)).unwrap_or(0.0)
        } else {
            cx.num(top, key, None).unwrap_or(0.0)
        }
    };
    let distortion = Distortion {
        k1: get(cx, "k1"),
        k2: get(cx, "k2"),
        k3: get(cx, "k3"),
        k4: get(cx, "k4"),
        p1: get(cx, "p1"),
        p2: get(cx, "p2"),
    };
    let model_s = if f.contains_key("camera_model") {
        cx.string(f, "camera_model", Some(&fr))
    } else {
        cx.string(top, "camera_model", None)
    };
    let model = match camera_model(model_s.as_deref(), &distortion) {
        Ok(m) => m,
        Err(reason) => {
            cx.invalid("camera_model", Some(&fr), reason);
            CameraModel::Pinhole
        }
    };
    let split = match cx.string(f, "split", Some(&fr)) {
        None => None,
        Some(s) => Split::parse(&s).or_else(|| {
            cx.invalid("split", Some(&fr), format!("`{s}` is not train/eval/test"));
            None
        }),
    };
    let mask_path = cx.string(f, "mask_path", Some(&fr)).map(|p| dir.join(p));
    let depth_path = cx.string(f, "depth_file_path", Some(&fr)).map(|p| dir.join(p));
    if cx.errors.len() > before {
        return None;
    }
    Some(RawFrame {
        index,
        name,
        file_path: file_path.map(|p| dir.join(p)),
        band_files: band_files.map(|v| v.into_iter().map(|p| dir.join(p)).collect()),
        mask_path,
        depth_path,
        c2w: c2w?,
        camera: Camera {
            model,
            fx: vals[0],
            fy: vals[1],
            cx: vals[2],
            cy: vals[3],
            width: vals[4] as u32,
            height: vals[5] as u32,
            distortion,
        },
        split,
    })
}

/// A `camera_model` name (absent or `PERSPECTIVE`: pinhole without distortion, OPENCV with it); the error is
/// the reason.
pub(super) fn camera_model(name: Option<&str>, distortion: &Distortion) -> Result<CameraModel, String> {
    match name {
        Some("PINHOLE") | Some("SIMPLE_PINHOLE") => Ok(CameraModel::Pinhole),
        Some("OPENCV") => Ok(CameraModel::OpenCv),
        Some("OPENCV_FISHEYE") => Ok(CameraModel::OpenCvFisheye),
        None | Some("PERSPECTIVE") if distortion.is_zero() => Ok(CameraModel::Pinhole),
        None | Some("PERSPECTIVE") => Ok(CameraModel::OpenCv),
        Some(o) => Err(format!("unsupported camera model `{o}`")),
    }
}

fn parse_matrix(cx: &mut Ctx, f: &Map<String, Value>, fr: &FrameRef) -> Option<Mat4> {
    let Some(v) = f.get("transform_matrix") else {
        cx.missing("transform_matrix", Some(fr));
        return None;
    };
    rigid_matrix(cx, v, "transform_matrix", Some(fr))
}

/// A 3x4 or 4x4 matrix whose rotation part is orthonormal with determinant +1.
pub(super) fn rigid_matrix(cx: &mut Ctx, v: &Value, key: &str, fr: Option<&FrameRef>) -> Option<Mat4> {
    let rows: Option<Vec<Vec<f64>>> = v.as_array().and_then(|rows| {
        rows.iter().map(|r| r.as_array().and_then(|r| r.iter().map(|x| x.as_f64()).collect())).collect()
    });
    let Some(rows) = rows else {
        cx.invalid(key, fr, "expected a 4x4 list of numbers");
        return None;
    };
    let ok_shape = (rows.len() == 4 || rows.len() == 3) && rows.iter().all(|r| r.len() == 4);
    if !ok_shape || rows.iter().flatten().any(|x| !x.is_finite()) {
        cx.invalid(key, fr, "expected a 4x4 list of finite numbers");
        return None;
    }
    let mut m = [[0.0; 4]; 4];
    m[3] = [0.0, 0.0, 0.0, 1.0];
    for (i, r) in rows.iter().take(3).enumerate() {
        m[i].copy_from_slice(r);
    }
    // Orthonormal rotation part: max |RᵀR − I| and det within 1e-3 of +1.
    let mut dev: f64 = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let d: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum();
            dev = dev.max((d - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    dev = dev.max((det - 1.0).abs());
    if dev > 1e-3 {
        if key == "transform_matrix" {
            cx.errors.push(DataError::NotOrthonormal {
                path: cx.path.to_path_buf(),
                frame: fr.cloned(),
                deviation: dev,
            });
        } else {
            cx.invalid(
                key,
                fr,
                format!("rotation part is not orthonormal with determinant +1 (max deviation {dev:.3e})"),
            );
        }
        return None;
    }
    Some(m)
}
