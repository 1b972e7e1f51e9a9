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

use super::error::PoseError;
use super::model::PoseModel;

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
    /// The model's CRS (described), now the dataset's `crs`.
    pub crs: Option<String>,
    /// The dataset's earlier `crs`, removed because the model is not georeferenced.
    pub crs_removed: Option<String>,
    /// The reader's notes (`PoseModel::notes`).
    pub notes: Vec<String>,
}

/// The file stem a frame or image is matched by.
pub fn stem(name: &str) -> String {
    let base = name.rsplit(['/', '\\']).next().unwrap_or(name);
    match base.rsplit_once('.') {
        Some((s, _)) if !s.is_empty() => s.to_string(),
        _ => base.to_string(),
    }
}

fn frame_name(f: &Value) -> Option<String> {
    f.get("file_path")
        .and_then(|v| v.as_str())
        .or_else(|| f.get("band_files").and_then(|b| b.get(0)).and_then(|v| v.as_str()))
        .map(str::to_string)
}

fn write_atomic(path: &Path, text: &str) -> Result<(), PoseError> {
    crate::util::atomic::write_bytes(path, text.as_bytes())
        .map_err(|e| PoseError::Dataset { path: path.to_path_buf(), reason: e.to_string() })
}

/// Puts the poses, intrinsics and points of `model` (read from `source`) into the dataset at `dataset`.
pub fn apply_poses(model: &PoseModel, source: &Path, dataset: &Path) -> Result<PoseImportReport, PoseError> {
    let tpath = transforms_path(dataset);
    let root = read_transforms(&tpath)?;
    apply_poses_to(model, source, &tpath, root)
}

/// `dataset`'s transforms.json (the folder's, or the file itself).
pub fn transforms_path(dataset: &Path) -> PathBuf {
    if dataset.is_file() {
        dataset.to_path_buf()
    } else {
        dataset.join("transforms.json")
    }
}

/// The parsed transforms.json at `tpath`.
pub fn read_transforms(tpath: &Path) -> Result<Value, PoseError> {
    let text = std::fs::read_to_string(tpath).map_err(PoseError::io(tpath))?;
    serde_json::from_str(&text).map_err(|e| PoseError::parse(tpath, "JSON", e.to_string()))
}

/// [`apply_poses`] on an already-read `root` of the transforms.json at `tpath` (which is backed up as it is on
/// disk, then replaced).
pub fn apply_poses_to(
    model: &PoseModel,
    source: &Path,
    tpath: &Path,
    mut root: Value,
) -> Result<PoseImportReport, PoseError> {
    let tpath = tpath.to_path_buf();
    let dir = tpath.parent().unwrap_or(Path::new(".")).to_path_buf();
    // Frames an earlier import left unregistered are candidates again.
    if let Some(Value::Array(mut old)) = root.as_object_mut().and_then(|o| o.remove("unregistered_frames")) {
        if let Some(Value::Array(f)) = root.get_mut("frames") {
            f.append(&mut old);
        }
    }
    let frames = root
        .get("frames")
        .and_then(|f| f.as_array())
        .cloned()
        .ok_or_else(|| PoseError::Dataset { path: tpath.clone(), reason: "no `frames` list".into() })?;
    // Frames by stem; two frames with one stem cannot be told apart. A frame made by `import rig` is also found by
    // the stem of its reference band's raw file (ODM and Metashape reconstruct the raw band files).
    let reference = root.get("reference_band").and_then(|v| v.as_str()).and_then(|r| {
        root.get("bands")?.as_array()?.iter().position(|b| b.get("name").and_then(|n| n.as_str()) == Some(r))
    });
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
        if let Some(src) = reference.and_then(|r| f.get("source_files")?.get(r)?.as_str().map(str::to_string)) {
            by_stem.entry(stem(&src)).or_insert(i);
        }
    }
    let mut posed: Vec<Option<Value>> = vec![None; frames.len()];
    let mut unknown_images = Vec::new();
    let mut image_frame: HashMap<u64, usize> = HashMap::new();
    for im in &model.images {
        let Some(&fi) = by_stem.get(&stem(&im.name)) else {
            unknown_images.push(im.name.clone());
            continue;
        };
        if image_frame.values().any(|&v| v == fi) {
            // Another image (another band of the same capture, in an ODM multispectral model) already posed it.
            unknown_images.push(im.name.clone());
            continue;
        }
        let c2w = im.c2w;
        let mut f = frames[fi].clone();
        let obj = f.as_object_mut().expect("frames are objects");
        // Size check against what the frame (or the top level) says; a model made on the images scaled by one factor
        // (full-size originals of a downscaled dataset, or images upsampled for feature detection) is scaled back.
        let size = |k: &str| obj.get(k).or_else(|| root.get(k)).and_then(|v| v.as_u64());
        let cam = match (size("w"), size("h")) {
            (Some(w), Some(h)) if (w, h) != (im.camera.width, im.camera.height) => {
                im.camera.scaled_to(w, h).ok_or_else(|| {
                    PoseError::parse(
                        source,
                        format!("image {}", im.name),
                        format!(
                            "{}'s camera is {}x{} but frame {:?} is {w}x{h} (not one scale factor on both axes): \
                             run the tool on the dataset's own images",
                            model.tool,
                            im.camera.width,
                            im.camera.height,
                            frame_name(&frames[fi]).unwrap_or_default()
                        ),
                    )
                })?
            }
            _ => im.camera.clone(),
        };
        for k in ["k1", "k2", "k3", "k4", "p1", "p2", "camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h"] {
            obj.remove(k);
        }
        obj.insert("w".into(), json!(cam.width));
        obj.insert("h".into(), json!(cam.height));
        obj.insert("camera_model".into(), json!(cam.model));
        for (k, v) in &cam.keys {
            obj.insert((*k).into(), json!(v));
        }
        obj.insert("transform_matrix".into(), json!(c2w));
        obj.insert(format!("{}_image_id", model.tool), json!(im.id));
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
    let mut n_err = 0usize;
    for p in &model.points {
        let mut names: Vec<String> =
            p.images.iter().filter_map(|id| image_frame.get(id)).filter_map(|&fi| frame_name(&frames[fi])).collect();
        names.sort();
        names.dedup();
        if names.is_empty() || !p.xyz.iter().all(|v| v.is_finite()) {
            continue;
        }
        track_sum += p.images.len();
        err_sum += p.error.unwrap_or(0.0);
        n_err += usize::from(p.error.is_some());
        let mut pt = json!({"xyz": p.xyz, "rgb": p.rgb, "frames": names});
        if let Some(e) = p.error {
            pt["error"] = json!(e);
        }
        pts.push(pt);
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
        json!({"from": model.tool, "model": source.display().to_string(), "registered": image_frame.len(),
               "convention": "the tool's world frame, OpenGL camera axes",
               "crs": model.crs.as_ref().map(|c| c.key())}),
    );
    // The poses' CRS replaces the dataset's; a model in a local frame takes the old `crs` away (GPS priors).
    let crs_removed = match &model.crs {
        Some(c) => obj.insert("crs".into(), json!(c.key())).and(None),
        None => obj.remove("crs").map(|v| v.as_str().map(str::to_string).unwrap_or_else(|| v.to_string())),
    };
    if n_pts > 0 {
        obj.insert("sparse_points_path".into(), json!("sparse_points.json"));
    }
    // What is written must load: the dataset's own parser checks the new poses and intrinsics (a NaN becomes a
    // JSON null, a focal length may be negative or degenerate) and names the frame and key, before anything is
    // written.
    crate::data::transforms::parse_value(&tpath, &root).map_err(|e| PoseError::Dataset {
        path: source.to_path_buf(),
        reason: format!("the imported poses are not usable, nothing was written: {e}"),
    })?;
    // Backup, then the new files.
    let mut backup = dir.join("transforms.before-poses.json");
    let mut k = 1;
    while backup.exists() {
        backup = dir.join(format!("transforms.before-poses-{k}.json"));
        k += 1;
    }
    std::fs::copy(&tpath, &backup).map_err(PoseError::io(&backup))?;
    if n_pts > 0 {
        write_atomic(&dir.join("sparse_points.json"), &serde_json::to_string(&json!({"points": pts})).expect("json"))?;
    }
    write_atomic(&tpath, &serde_json::to_string_pretty(&root).expect("json"))?;
    Ok(PoseImportReport {
        source: format!("{} ({})", source.display(), model.tool),
        frames: frames.len(),
        registered: image_frame.len(),
        unregistered,
        unknown_images,
        points: n_pts,
        mean_reprojection_error_px: (n_err > 0).then(|| err_sum / n_err as f64),
        mean_track_length: (n_pts > 0).then(|| track_sum as f64 / n_pts as f64),
        backup: Some(backup),
        crs: model.crs.as_ref().map(|c| c.describe()),
        crs_removed,
        notes: model.notes.clone(),
    })
}
