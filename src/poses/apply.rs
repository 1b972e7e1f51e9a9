//! Writes imported poses into a dataset: each frame matched to a model image by file stem (the name without
//! folders and extension, so `images/IMG_0001.tif` matches COLMAP's `IMG_0001.png` or `rgb/IMG_0001.jpg`), its
//! `transform_matrix` and per-frame intrinsics replaced, the model's points written as `sparse_points.json`
//! (docs/dataset.md) for depth supervision. Frames the model did not register leave `frames` for
//! `unregistered_frames` (listed, kept whole); model images the dataset lacks are listed. The old
//! `transforms.json` is kept as `transforms.before-poses.json` (numbered if taken); new files are written to a
//! temporary name and renamed.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use super::colmap::{c2w_opengl, ColmapCamera, ColmapModel};
use super::error::PoseError;

/// What an import did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PoseImportReport {
    pub source: String,
    pub frames: usize,
    pub registered: usize,
    /// Dataset frames the model has no pose for (moved to `unregistered_frames`).
    pub unregistered: Vec<String>,
    /// Model images that match no dataset frame.
    pub unknown_images: Vec<String>,
    pub points: usize,
    pub mean_reprojection_error_px: Option<f64>,
    pub mean_track_length: Option<f64>,
    pub backup: Option<PathBuf>,
}

/// The file stem a frame or image is matched by.
pub fn stem(name: &str) -> String {
    let base = name.rsplit(['/', '\\']).next().unwrap_or(name);
    match base.rsplit_once('.') {
        Some((s, _)) if !s.is_empty() => s.to_string(),
        _ => base.to_string(),
    }
}

/// msnerf's per-frame camera keys for a COLMAP camera.
fn camera_keys(c: &ColmapCamera, path: &Path, image: &str) -> Result<Vec<(&'static str, Value)>, PoseError> {
    let p = &c.params;
    let mut k: Vec<(&'static str, Value)> = vec![("w", json!(c.width)), ("h", json!(c.height))];
    let (model, fx, fy, cx, cy, dist): (&str, f64, f64, f64, f64, Vec<(&'static str, f64)>) = match c.model.as_str() {
        "SIMPLE_PINHOLE" => ("PINHOLE", p[0], p[0], p[1], p[2], vec![]),
        "PINHOLE" => ("PINHOLE", p[0], p[1], p[2], p[3], vec![]),
        "SIMPLE_RADIAL" => ("OPENCV", p[0], p[0], p[1], p[2], vec![("k1", p[3])]),
        "RADIAL" => ("OPENCV", p[0], p[0], p[1], p[2], vec![("k1", p[3]), ("k2", p[4])]),
        "OPENCV" => ("OPENCV", p[0], p[1], p[2], p[3], vec![("k1", p[4]), ("k2", p[5]), ("p1", p[6]), ("p2", p[7])]),
        "OPENCV_FISHEYE" => (
            "OPENCV_FISHEYE",
            p[0],
            p[1],
            p[2],
            p[3],
            vec![("k1", p[4]), ("k2", p[5]), ("k3", p[6]), ("k4", p[7])],
        ),
        "FULL_OPENCV" if p[9..12].iter().all(|v| *v == 0.0) => (
            "OPENCV",
            p[0],
            p[1],
            p[2],
            p[3],
            vec![("k1", p[4]), ("k2", p[5]), ("p1", p[6]), ("p2", p[7]), ("k3", p[8])],
        ),
        other => {
            return Err(PoseError::parse(
                path,
                format!("camera {} (image {image})", c.id),
                format!("camera model {other} has no msnerf equivalent (PINHOLE, OPENCV and OPENCV_FISHEYE families are supported); rerun COLMAP's mapper with --ImageReader.camera_model OPENCV"),
            ))
        }
    };
    k.push(("camera_model", json!(model)));
    k.extend([("fl_x", json!(fx)), ("fl_y", json!(fy)), ("cx", json!(cx)), ("cy", json!(cy))]);
    for (name, v) in dist {
        k.push((name, json!(v)));
    }
    Ok(k)
}

fn frame_name(f: &Value) -> Option<String> {
    f.get("file_path")
        .and_then(|v| v.as_str())
        .or_else(|| f.get("band_files").and_then(|b| b.get(0)).and_then(|v| v.as_str()))
        .map(str::to_string)
}

fn write_atomic(path: &Path, text: &str) -> Result<(), PoseError> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    std::fs::write(&tmp, text).map_err(PoseError::io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(PoseError::io(path))
}

/// Puts the poses, intrinsics and points of `model` (read from `source`) into the dataset at `dataset`.
pub fn apply_colmap(model: &ColmapModel, source: &Path, dataset: &Path) -> Result<PoseImportReport, PoseError> {
    let tpath = if dataset.is_file() { dataset.to_path_buf() } else { dataset.join("transforms.json") };
    let dir = tpath.parent().unwrap_or(Path::new(".")).to_path_buf();
    let text = std::fs::read_to_string(&tpath).map_err(PoseError::io(&tpath))?;
    let mut root: Value = serde_json::from_str(&text).map_err(|e| PoseError::parse(&tpath, "JSON", e.to_string()))?;
    let frames = root
        .get("frames")
        .and_then(|f| f.as_array())
        .cloned()
        .ok_or_else(|| PoseError::Dataset { path: tpath.clone(), reason: "no `frames` list".into() })?;
    // Frames by stem; two frames with one stem cannot be told apart.
    let mut by_stem: HashMap<String, usize> = HashMap::new();
    for (i, f) in frames.iter().enumerate() {
        let name = frame_name(f).ok_or_else(|| PoseError::Dataset {
            path: tpath.clone(),
            reason: format!("frame {i} has neither file_path nor band_files"),
        })?;
        if let Some(prev) = by_stem.insert(stem(&name), i) {
            return Err(PoseError::Dataset {
                path: tpath.clone(),
                reason: format!(
                    "frames {prev} and {i} share the file stem {:?}: images cannot be matched by name",
                    stem(&name)
                ),
            });
        }
    }
    let mut posed: Vec<Option<Value>> = vec![None; frames.len()];
    let mut unknown_images = Vec::new();
    let mut image_frame: HashMap<u32, usize> = HashMap::new();
    for im in &model.images {
        let Some(&fi) = by_stem.get(&stem(&im.name)) else {
            unknown_images.push(im.name.clone());
            continue;
        };
        let cam = model.cameras.get(&im.camera_id).ok_or_else(|| {
            PoseError::parse(
                source,
                format!("image {}", im.name),
                format!("camera {} is not in the model", im.camera_id),
            )
        })?;
        let c2w = c2w_opengl(im.q, im.t).map_err(|e| PoseError::parse(source, format!("image {}", im.name), e))?;
        let mut f = frames[fi].clone();
        let obj = f.as_object_mut().expect("frames are objects");
        // Size check against what the frame (or the top level) says.
        let size = |k: &str| obj.get(k).or_else(|| root.get(k)).and_then(|v| v.as_u64());
        if let (Some(w), Some(h)) = (size("w"), size("h")) {
            if (w, h) != (cam.width, cam.height) {
                return Err(PoseError::parse(
                    source,
                    format!("image {}", im.name),
                    format!(
                        "COLMAP's camera is {}x{} but frame {:?} is {w}x{h}: run COLMAP on the dataset's own images",
                        cam.width,
                        cam.height,
                        frame_name(&frames[fi]).unwrap_or_default()
                    ),
                ));
            }
        }
        for k in ["k1", "k2", "k3", "k4", "p1", "p2", "camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h"] {
            obj.remove(k);
        }
        for (k, v) in camera_keys(cam, source, &im.name)? {
            obj.insert(k.into(), v);
        }
        obj.insert("transform_matrix".into(), json!(c2w));
        obj.insert("colmap_image_id".into(), json!(im.id));
        posed[fi] = Some(f);
        image_frame.insert(im.id, fi);
    }
    if image_frame.is_empty() {
        let sample: Vec<&str> = model.images.iter().take(3).map(|i| i.name.as_str()).collect();
        return Err(PoseError::Dataset {
            path: tpath.clone(),
            reason: format!(
                "no image of {} matches a frame of the dataset by file stem (model images: {sample:?})",
                source.display()
            ),
        });
    }
    let mut unregistered = Vec::new();
    let mut out_frames = Vec::new();
    let mut unreg_frames = Vec::new();
    for (f, p) in frames.iter().zip(posed) {
        match p {
            Some(v) => out_frames.push(v),
            None => {
                unregistered.push(frame_name(f).unwrap_or_default());
                unreg_frames.push(f.clone());
            }
        }
    }
    // Sparse points in the poses' frame, tracks by frame name.
    let mut pts = Vec::new();
    let mut track_sum = 0usize;
    let mut err_sum = 0.0;
    for p in &model.points {
        let mut names: Vec<String> =
            p.images.iter().filter_map(|id| image_frame.get(id)).filter_map(|&fi| frame_name(&frames[fi])).collect();
        names.sort();
        names.dedup();
        if names.is_empty() || !p.xyz.iter().all(|v| v.is_finite()) {
            continue;
        }
        track_sum += p.images.len();
        err_sum += p.error;
        pts.push(json!({"xyz": p.xyz, "error": p.error, "rgb": p.rgb, "frames": names}));
    }
    let n_pts = pts.len();
    let obj = root.as_object_mut().expect("object");
    obj.insert("frames".into(), Value::Array(out_frames));
    if !unreg_frames.is_empty() {
        obj.insert("unregistered_frames".into(), Value::Array(unreg_frames));
    }
    for k in ["camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2", "pose_prior"] {
        obj.remove(k);
    }
    obj.insert(
        "pose_source".into(),
        json!({"from": "colmap", "model": source.display().to_string(), "registered": image_frame.len(), "convention": "COLMAP world frame, OpenGL camera axes"}),
    );
    // Backup, then the new files.
    let mut backup = dir.join("transforms.before-poses.json");
    let mut k = 1;
    while backup.exists() {
        backup = dir.join(format!("transforms.before-poses-{k}.json"));
        k += 1;
    }
    std::fs::copy(&tpath, &backup).map_err(PoseError::io(&backup))?;
    if n_pts > 0 {
        obj.insert("sparse_points_path".into(), json!("sparse_points.json"));
        write_atomic(&dir.join("sparse_points.json"), &serde_json::to_string(&json!({"points": pts})).expect("json"))?;
    }
    write_atomic(&tpath, &serde_json::to_string_pretty(&root).expect("json"))?;
    Ok(PoseImportReport {
        source: source.display().to_string(),
        frames: frames.len(),
        registered: image_frame.len(),
        unregistered,
        unknown_images,
        points: n_pts,
        mean_reprojection_error_px: (n_pts > 0).then(|| err_sum / n_pts as f64),
        mean_track_length: (n_pts > 0).then(|| track_sum as f64 / n_pts as f64),
        backup: Some(backup),
    })
}
