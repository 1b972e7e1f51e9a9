//! Sparse 3-D points with the frames that observed them (`sparse_points_path` in `transforms.json`): what an SfM
//! reconstruction leaves (COLMAP's `points3D` tracks), or what the simulator writes from its truth. Depth
//! supervision (`loss.depth.source: sparse_points`) projects each point into the training frames of its track.
//!
//! ```json
//! {"points": [{"xyz": [12.1, -3.4, 0.25], "error": 0.6, "frames": ["images/f0003.tif", "images/f0004.tif"]}]}
//! ```
//! `xyz` is in the frame of `transform_matrix` (the dataset's world, its units); `frames` name frames by their
//! `file_path` (or first `band_files` entry) as written in `transforms.json`; `error` (optional) is the mean
//! reprojection error in pixels. Other keys of a point (`rgb`, ids) are ignored.

use super::{DataError, Dataset};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::Path;

/// One point of the file, its frames resolved to dataset frame indices.
#[derive(Clone, Debug, PartialEq)]
pub struct SparsePoint {
    pub xyz: [f64; 3],
    /// Mean reprojection error in pixels, when the file gives one.
    pub error: Option<f64>,
    /// Indices into `Dataset::frames`.
    pub frames: Vec<usize>,
}

#[derive(Deserialize)]
struct FilePoint {
    xyz: Vec<f64>,
    #[serde(default)]
    error: Option<f64>,
    frames: Vec<String>,
}

#[derive(Deserialize)]
struct File {
    points: Vec<FilePoint>,
}

fn invalid(path: &Path, key: String, reason: impl Into<String>) -> DataError {
    DataError::InvalidValue { path: path.to_path_buf(), key, frame: None, reason: reason.into() }
}

/// Reads `path`, resolving frame names against `ds`. Errors name the file and the point (`points[i]`) and key.
pub fn read_sparse_points(ds: &Dataset, path: &Path) -> Result<Vec<SparsePoint>, DataError> {
    let file: File = super::transforms::read_json(path, "sparse_points_path")?;
    let by_name: HashMap<&str, usize> = ds.frames.iter().enumerate().map(|(i, f)| (f.name.as_str(), i)).collect();
    let mut out = Vec::with_capacity(file.points.len());
    let mut errors = Vec::new();
    for (i, p) in file.points.into_iter().enumerate() {
        if p.xyz.len() != 3 || !p.xyz.iter().all(|v| v.is_finite()) {
            errors.push(invalid(path, format!("points[{i}].xyz"), format!("need 3 finite numbers, got {:?}", p.xyz)));
            continue;
        }
        if let Some(e) = p.error.filter(|e| !(e.is_finite() && *e >= 0.0)) {
            errors.push(invalid(path, format!("points[{i}].error"), format!("must be finite and >= 0, got {e}")));
            continue;
        }
        let mut frames = Vec::with_capacity(p.frames.len());
        for name in &p.frames {
            match by_name.get(name.as_str()) {
                Some(&f) => frames.push(f),
                None => errors.push(invalid(
                    path,
                    format!("points[{i}].frames"),
                    format!("no frame `{name}` in {}", ds.transforms_path.display()),
                )),
            }
        }
        if p.frames.is_empty() {
            errors.push(invalid(path, format!("points[{i}].frames"), "a point needs at least one observing frame"));
        }
        let mut xyz = [p.xyz[0], p.xyz[1], p.xyz[2]];
        if let Some(u) = &ds.applied_transform_undone {
            xyz = std::array::from_fn(|r| u[r][0] * xyz[0] + u[r][1] * xyz[1] + u[r][2] * xyz[2] + u[r][3]);
        }
        out.push(SparsePoint { xyz, error: p.error, frames });
    }
    match DataError::from_list(errors) {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

/// A point as the file holds it: frames by name.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedPoint {
    pub xyz: [f64; 3],
    pub error: Option<f64>,
    pub frames: Vec<String>,
}

/// Writes points in the format above, atomically.
pub fn write_sparse_points(path: &Path, points: &[NamedPoint]) -> Result<(), crate::util::atomic::WriteError> {
    let pts: Vec<serde_json::Value> = points
        .iter()
        .map(|p| {
            let mut v = serde_json::json!({"xyz": p.xyz, "frames": p.frames});
            if let Some(e) = p.error {
                v["error"] = serde_json::json!(e);
            }
            v
        })
        .collect();
    let doc = serde_json::json!({ "points": pts });
    crate::util::atomic::write_bytes(path, serde_json::to_string(&doc).expect("json").as_bytes())
}
