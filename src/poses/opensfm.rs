//! OpenSfM reconstructions (`reconstruction.json`; OpenDroneMap keeps one in `PROJECT/opensfm/`), as OpenSfM's
//! `types.py`/`io.py` write them:
//! - shots: `rotation` is an axis-angle vector (Rodrigues) and `translation` t of the world-to-camera map
//!   `x_cam = R x_world + t`, camera axes x right, y down, z forward (as OpenCV);
//! - cameras: focal lengths and principal-point offsets are *normalised by max(width, height)* and the principal
//!   point is measured from the image centre: `fl = focal * size`, `cx = width / 2 + c_x * size` (pixel-corner
//!   coordinates, the dataset's convention). Projection types: perspective (focal, k1, k2), simple_radial,
//!   radial, brown (focal_x/y, c_x/y, k1, k2, p1, p2, k3), fisheye (focal, k1, k2), fisheye_opencv;
//! - points carry no track: their tracks come from `tracks.csv` beside the reconstruction when it is there.
//!
//! The first (largest) reconstruction of the file is used. ODM (`--from odm PROJECT`): the reconstruction is in the
//! projected CRS minus the offset of `odm_georeferencing/coords.txt` (its first line names the CRS, its second
//! gives easting and northing); the offset is added back so poses and points are in the CRS's metres. An ODM
//! multispectral project has one camera per band; each shot's own camera is used.

use std::collections::HashMap;
use std::path::Path;

use serde_json::Value;

use super::error::PoseError;
use super::model::{c2w_from_w2c_opencv, PoseCamera, PoseModel, PosePoint, PosedImage};

fn f(v: &Value, key: &str, path: &Path, at: &str) -> Result<f64, PoseError> {
    v.get(key).and_then(|x| x.as_f64()).ok_or_else(|| PoseError::parse(path, at, format!("missing number `{key}`")))
}

fn camera(c: &Value, path: &Path, id: &str) -> Result<PoseCamera, PoseError> {
    let at = format!("camera {id}");
    let g = |k: &str| f(c, k, path, &at);
    let opt = |k: &str| c.get(k).and_then(|x| x.as_f64()).unwrap_or(0.0);
    let (w, h) = (g("width")?, g("height")?);
    let size = w.max(h);
    let pt = c.get("projection_type").and_then(|x| x.as_str()).unwrap_or("perspective");
    let centre = |cx: f64, cy: f64| [("cx", w / 2.0 + cx * size), ("cy", h / 2.0 + cy * size)];
    let (model, mut keys): (&'static str, Vec<(&'static str, f64)>) = match pt {
        "perspective" => {
            let fl = g("focal")? * size;
            ("OPENCV", vec![("fl_x", fl), ("fl_y", fl), ("k1", opt("k1")), ("k2", opt("k2"))])
        }
        "simple_radial" | "radial" | "brown" => {
            let k = [("k1", opt("k1")), ("k2", opt("k2")), ("p1", opt("p1")), ("p2", opt("p2")), ("k3", opt("k3"))];
            let mut v = vec![("fl_x", g("focal_x")? * size), ("fl_y", g("focal_y")? * size)];
            v.extend(centre(opt("c_x"), opt("c_y")));
            v.extend(k);
            ("OPENCV", v)
        }
        "fisheye" => {
            let fl = g("focal")? * size;
            ("OPENCV_FISHEYE", vec![("fl_x", fl), ("fl_y", fl), ("k1", opt("k1")), ("k2", opt("k2"))])
        }
        "fisheye_opencv" => {
            let mut v = vec![("fl_x", g("focal_x")? * size), ("fl_y", g("focal_y")? * size)];
            v.extend(centre(opt("c_x"), opt("c_y")));
            v.extend([("k1", opt("k1")), ("k2", opt("k2")), ("k3", opt("k3")), ("k4", opt("k4"))]);
            ("OPENCV_FISHEYE", v)
        }
        other => {
            return Err(PoseError::parse(
                path,
                at,
                format!("projection type {other} has no msnerf equivalent (perspective, simple_radial, radial, brown, fisheye, fisheye_opencv)"),
            ))
        }
    };
    if !keys.iter().any(|(k, _)| *k == "cx") {
        keys.extend(centre(0.0, 0.0));
    }
    Ok(PoseCamera { width: w as u64, height: h as u64, model, keys })
}

/// Rotation matrix of an axis-angle vector (Rodrigues).
pub fn rodrigues(v: [f64; 3]) -> [[f64; 3]; 3] {
    let theta = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if theta < 1e-15 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = v.map(|x| x / theta);
    let (s, c) = theta.sin_cos();
    let kx = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    std::array::from_fn(|i| {
        std::array::from_fn(|j| (if i == j { c } else { 0.0 }) + (1.0 - c) * k[i] * k[j] + s * kx[i][j])
    })
}

fn vec3(v: &Value, key: &str, path: &Path, at: &str) -> Result<[f64; 3], PoseError> {
    let a =
        v.get(key).and_then(|x| x.as_array()).ok_or_else(|| PoseError::parse(path, at, format!("missing `{key}`")))?;
    let n: Vec<f64> = a.iter().filter_map(|x| x.as_f64()).collect();
    if n.len() != 3 || !n.iter().all(|x| x.is_finite()) {
        return Err(PoseError::parse(path, at, format!("`{key}` is not three finite numbers")));
    }
    Ok([n[0], n[1], n[2]])
}

/// Tracks from OpenSfM's `tracks.csv` (image, track id, ...; tab-separated, a version line first): track -> images.
fn read_tracks(path: &Path) -> Result<HashMap<String, Vec<String>>, PoseError> {
    let text = std::fs::read_to_string(path).map_err(PoseError::io(path))?;
    let mut out: HashMap<String, Vec<String>> = HashMap::new();
    for (i, line) in text.lines().enumerate() {
        if line.starts_with("OPENSFM_TRACKS_VERSION") || line.trim().is_empty() {
            continue;
        }
        let mut it = line.split('\t');
        let (Some(image), Some(track)) = (it.next(), it.next()) else {
            return Err(PoseError::parse(path, format!("line {}", i + 1), "expected image<TAB>track_id<TAB>..."));
        };
        out.entry(track.to_string()).or_default().push(image.to_string());
    }
    Ok(out)
}

/// Reads `reconstruction.json` (and `tracks.csv` beside it when present).
pub fn read_reconstruction(path: &Path) -> Result<PoseModel, PoseError> {
    let text = std::fs::read_to_string(path).map_err(PoseError::io(path))?;
    let root: Value = serde_json::from_str(&text).map_err(|e| PoseError::parse(path, "JSON", e.to_string()))?;
    let rec = root
        .as_array()
        .and_then(|a| a.first())
        .ok_or_else(|| PoseError::parse(path, "top level", "expected a list of reconstructions"))?;
    let cams = rec
        .get("cameras")
        .and_then(|c| c.as_object())
        .ok_or_else(|| PoseError::parse(path, "reconstruction 0", "no `cameras`"))?;
    let mut cameras = HashMap::new();
    for (id, c) in cams {
        cameras.insert(id.clone(), camera(c, path, id)?);
    }
    let shots = rec
        .get("shots")
        .and_then(|s| s.as_object())
        .ok_or_else(|| PoseError::parse(path, "reconstruction 0", "no `shots`"))?;
    let mut images = Vec::with_capacity(shots.len());
    let mut ids: HashMap<String, u64> = HashMap::new();
    let mut names: Vec<&String> = shots.keys().collect();
    names.sort();
    for (k, name) in names.into_iter().enumerate() {
        let s = &shots[name];
        let at = format!("shot {name}");
        let r = rodrigues(vec3(s, "rotation", path, &at)?);
        let t = vec3(s, "translation", path, &at)?;
        let cam_id =
            s.get("camera").and_then(|c| c.as_str()).ok_or_else(|| PoseError::parse(path, &at, "no `camera`"))?;
        let camera = cameras
            .get(cam_id)
            .cloned()
            .ok_or_else(|| PoseError::parse(path, &at, format!("camera {cam_id:?} is not in `cameras`")))?;
        ids.insert(name.clone(), k as u64);
        images.push(PosedImage { id: k as u64, name: name.clone(), c2w: c2w_from_w2c_opencv(r, t), camera });
    }
    let tracks_path = path.with_file_name("tracks.csv");
    let tracks = if tracks_path.is_file() { read_tracks(&tracks_path)? } else { HashMap::new() };
    let mut points = Vec::new();
    if let Some(pts) = rec.get("points").and_then(|p| p.as_object()) {
        for (id, p) in pts {
            let at = format!("point {id}");
            let xyz = vec3(p, "coordinates", path, &at)?;
            let rgb = p.get("color").and_then(|c| c.as_array()).map(|c| {
                std::array::from_fn(|i| c.get(i).and_then(|x| x.as_f64()).unwrap_or(0.0).clamp(0.0, 255.0) as u8)
            });
            let imgs =
                tracks.get(id).map(|v| v.iter().filter_map(|n| ids.get(n).copied()).collect()).unwrap_or_default();
            points.push(PosePoint { xyz, rgb: rgb.unwrap_or([0; 3]), error: None, images: imgs });
        }
    }
    Ok(PoseModel { tool: "opensfm", images, points, crs: None, notes: Vec::new() })
}

/// Reads an ODM project: `opensfm/reconstruction.json` plus the offset and CRS of `odm_georeferencing/coords.txt`.
pub fn read_odm(project: &Path) -> Result<PoseModel, PoseError> {
    let rec = project.join("opensfm").join("reconstruction.json");
    if !rec.is_file() {
        return Err(PoseError::Dataset {
            path: project.to_path_buf(),
            reason: "not an ODM project: no opensfm/reconstruction.json".into(),
        });
    }
    let mut m = read_reconstruction(&rec)?;
    m.tool = "odm";
    let coords = project.join("odm_georeferencing").join("coords.txt");
    if coords.is_file() {
        let text = std::fs::read_to_string(&coords).map_err(PoseError::io(&coords))?;
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let crs = lines
            .next()
            .map(|l| {
                crate::geo::Crs::parse(l).map_err(|e| PoseError::parse(&coords, "line 1 (the CRS)", e.to_string()))
            })
            .transpose()?;
        let off: Vec<f64> = lines
            .next()
            .map(|l| l.split_whitespace().filter_map(|x| x.parse::<f64>().ok()).collect())
            .unwrap_or_default();
        if off.len() < 2 {
            return Err(PoseError::parse(&coords, "line 2", "expected the easting and northing offset"));
        }
        for im in &mut m.images {
            im.c2w[0][3] += off[0];
            im.c2w[1][3] += off[1];
        }
        for p in &mut m.points {
            p.xyz[0] += off[0];
            p.xyz[1] += off[1];
        }
        m.crs = crs;
    }
    Ok(m)
}
