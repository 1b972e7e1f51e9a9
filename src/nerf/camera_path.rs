//! Camera paths for `msnerf render --views PATH.json`, in two formats:
//!
//! 1. **nerfstudio's viewer `camera_path.json`** (what `ns-render camera-path` reads): an object with
//!    `camera_path`: [{`camera_to_world`: 16 numbers, row-major 4x4, `fov`: vertical degrees, `aspect`}],
//!    `render_width`, `render_height` and optionally `camera_type` (only `perspective`). Its poses are in
//!    nerfstudio's **normalised** frame (the viewer's scene; ns-render hands them to the model unchanged), which is
//!    msnerf's normalised frame too (same dataparser, `dataparser_transforms.json` in the run folder): they are used
//!    as they are. Intrinsics as nerfstudio builds them: fx = fy = (H/2)/tan(fov/2), principal point at the centre.
//!    Size: `render_width` x `render_height`; with one of them missing, the other follows from `aspect` (or the
//!    dataset's aspect); with both missing, the dataset's size. Without `fov`, the dataset's vertical FOV.
//! 2. **transforms.json-style frames**: a list of frames (or an object with `frames`), each with
//!    `transform_matrix` (4x4 rows, or 16 numbers), in the **dataset's world frame** like the dataset's own
//!    transforms.json; rendered with the dataset's intrinsics (first frame's camera).
//!
//! Errors name the file, the key and the index of the entry at fault.

use super::error::{NerfError, NerfResult};
use super::views::NovelView;
use crate::data::pose::Mat4;
use crate::data::{Camera, CameraModel, Dataset, Distortion, PoseTransform};
use serde_json::Value;
use std::path::Path;

/// Largest accepted `render_width` / `render_height`.
pub const MAX_RENDER_SIZE: u64 = 16384;

/// `key` names the matrix's key in `path` (`camera_path[3].camera_to_world`).
fn matrix(v: &Value, path: &Path, key: &dyn Fn() -> String) -> NerfResult<Mat4> {
    let err = |reason: String| NerfError::key(path, key(), reason);
    let flat: Vec<&Value> = match v {
        Value::Array(rows) if rows.len() == 4 && rows.iter().all(|r| r.is_array()) => {
            rows.iter().flat_map(|r| r.as_array().expect("checked").iter()).collect()
        }
        Value::Array(a) => a.iter().collect(),
        _ => return Err(err(format!("expected a 4x4 matrix (16 numbers), got {v}"))),
    };
    if flat.len() != 16 {
        return Err(err(format!("expected 16 numbers (a 4x4 matrix), got {}", flat.len())));
    }
    let mut m = [[0.0; 4]; 4];
    for (i, x) in flat.iter().enumerate() {
        m[i / 4][i % 4] = x
            .as_f64()
            .filter(|f| f.is_finite())
            .ok_or_else(|| err(format!("element {i} is not a finite number: {x}")))?;
    }
    let r = |i: usize, j: usize| m[i][j];
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1)) - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    if det.abs() < 1e-6 {
        return Err(err(format!("the 3x3 rotation part is singular (determinant {det:e})")));
    }
    Ok(m)
}

fn size(obj: &Value, key: &str, path: &Path) -> NerfResult<Option<u32>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => match v.as_u64() {
            Some(n) if (1..=MAX_RENDER_SIZE).contains(&n) => Ok(Some(n as u32)),
            _ => Err(NerfError::key(
                path,
                key,
                format!("expected a whole number of pixels from 1 to {MAX_RENDER_SIZE}, got {v}"),
            )),
        },
    }
}

fn positive(obj: &Value, key: &str, path: &Path, what: &dyn Fn() -> String, below: f64) -> NerfResult<Option<f64>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => match v.as_f64() {
            Some(x) if x > 0.0 && x < below => Ok(Some(x)),
            _ => Err(NerfError::key(
                path,
                format!("{}.{key}", what()),
                format!("expected a number above 0 and below {below}, got {v}"),
            )),
        },
    }
}

/// Reads a camera path (either format) for dataset `ds`; the views come back in the normalised frame.
pub fn load_camera_path(path: &Path, ds: &Dataset, transform: &PoseTransform) -> NerfResult<Vec<NovelView>> {
    let text = std::fs::read_to_string(path).map_err(|e| NerfError::file(path, e))?;
    let json: Value = serde_json::from_str(&text).map_err(|e| NerfError::file(path, format!("not valid JSON: {e}")))?;
    let base = ds.frames.first().ok_or_else(|| NerfError::file(&ds.root, "the dataset has no frames"))?.camera;
    let bad = |key: &str, reason: String| NerfError::key(path, key, reason);
    let named = |k: usize, c2w: Mat4, camera: Camera| NovelView { name: format!("path_{k:03}"), camera, c2w };
    if let Some(cp) = json.get("camera_path") {
        let entries = cp.as_array().ok_or_else(|| bad("camera_path", "expected a list of cameras".into()))?;
        if entries.is_empty() {
            return Err(bad("camera_path", "the list is empty".into()));
        }
        if let Some(t) = json.get("camera_type") {
            if !t.as_str().is_some_and(|s| s.eq_ignore_ascii_case("perspective")) {
                return Err(bad("camera_type", format!("only `perspective` can be rendered, got {t}")));
            }
        }
        let (w, h) = (size(&json, "render_width", path)?, size(&json, "render_height", path)?);
        let first = || "camera_path[0]".to_string();
        let aspect =
            positive(&entries[0], "aspect", path, &first, 1e3)?.unwrap_or(base.width as f64 / base.height as f64);
        let (w, h) = match (w, h) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, ((w as f64 / aspect).round() as u32).max(1)),
            (None, Some(h)) => (((h as f64 * aspect).round() as u32).max(1), h),
            (None, None) => (base.width, base.height),
        };
        let base_fov = 2.0 * (base.height as f64 / (2.0 * base.fy)).atan().to_degrees();
        return entries
            .iter()
            .enumerate()
            .map(|(k, e)| {
                let what = || format!("camera_path[{k}]");
                if !e.is_object() {
                    return Err(bad(&what(), "expected an object with camera_to_world and fov".into()));
                }
                let c2w = matrix(
                    e.get("camera_to_world").ok_or_else(|| bad(&what(), "key `camera_to_world` missing".into()))?,
                    path,
                    &|| format!("{}.camera_to_world", what()),
                )?;
                positive(e, "aspect", path, &what, 1e3)?;
                let fov = positive(e, "fov", path, &what, 180.0)?.unwrap_or(base_fov);
                let f = h as f64 / 2.0 / (fov.to_radians() / 2.0).tan();
                let camera = Camera {
                    model: CameraModel::Pinhole,
                    fx: f,
                    fy: f,
                    cx: w as f64 / 2.0,
                    cy: h as f64 / 2.0,
                    width: w,
                    height: h,
                    distortion: Distortion::default(),
                };
                Ok(named(k, c2w, camera))
            })
            .collect();
    }
    let (frames, key) = match &json {
        Value::Array(a) => (a, ""),
        Value::Object(o) => match o.get("frames").and_then(Value::as_array) {
            Some(a) => (a, "frames"),
            None => {
                return Err(NerfError::file(
                    path,
                    "expected nerfstudio's camera path (key `camera_path`), a list of frames with \
                     `transform_matrix`, or an object with `frames`",
                ))
            }
        },
        _ => return Err(NerfError::file(path, format!("expected a JSON object or list, got {json}"))),
    };
    if frames.is_empty() {
        return Err(bad(if key.is_empty() { "top level" } else { key }, "the list of frames is empty".into()));
    }
    frames
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let what = || format!("{key}[{k}]");
            let m = f.get("transform_matrix").ok_or_else(|| bad(&what(), "key `transform_matrix` missing".into()))?;
            let c2w = matrix(m, path, &|| format!("{}.transform_matrix", what()))?;
            Ok(named(k, transform.pose_to_normalized(&c2w), base))
        })
        .collect()
}
