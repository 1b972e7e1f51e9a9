//! Ground control in `sfm`: the dataset's `ground_control` (written by `import rig` from OpenDroneMap's
//! `gcp_list.txt`; docs/dataset.md) read back, and each point placed in the model's frame from its pixels in the
//! registered frames: the least-squares point nearest to the observations' rays (each pixel undistorted with the
//! frame's camera), then reprojected. An observation more than [`MAX_REPROJECTION_PX`] from the reprojection of
//! the others (a mis-click, or a point clicked in the wrong image) is dropped and named; a point needs two views
//! whose rays meet at [`MIN_ANGLE_DEG`] or more. [`super::georef`] fits the model to the points.

use std::collections::HashMap;

use serde_json::Value;

use crate::poses::apply::stem;
use crate::poses::model::{PoseCamera, PoseModel, PosedImage};

/// Reprojection error (pixels) above which an observation is dropped.
pub const MAX_REPROJECTION_PX: f64 = 5.0;
/// Smallest angle between two rays of a point (degrees).
pub const MIN_ANGLE_DEG: f64 = 2.0;

/// A surveyed point with its pixels in the dataset's frames.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlPoint {
    pub name: String,
    /// In the dataset's CRS.
    pub xyz: [f64; 3],
    /// `(frame file_path, pixel)`, the frame's corner at (0, 0).
    pub observations: Vec<(String, [f64; 2])>,
}

/// The dataset's ground control: the CRS its coordinates are in and the points.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundControl {
    pub crs: String,
    pub points: Vec<ControlPoint>,
}

/// Reads `ground_control` from `root` (None when the dataset has none); errors name the key.
pub fn read_ground_control(root: &Value) -> Result<Option<GroundControl>, String> {
    let Some(gc) = root.get("ground_control") else { return Ok(None) };
    let crs = gc.get("crs").and_then(|c| c.as_str()).ok_or("ground_control.crs: missing or not a string")?;
    let pts = gc.get("points").and_then(|p| p.as_array()).ok_or("ground_control.points: missing or not a list")?;
    let mut points = Vec::with_capacity(pts.len());
    for (i, p) in pts.iter().enumerate() {
        let key = |k: &str| format!("ground_control.points[{i}].{k}");
        let name = p.get("name").and_then(|n| n.as_str()).ok_or_else(|| format!("{}: missing", key("name")))?;
        let xyz = p
            .get("xyz")
            .and_then(|v| v.as_array())
            .filter(|a| a.len() == 3)
            .and_then(|a| Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?]))
            .filter(|v| v.iter().all(|c| c.is_finite()))
            .ok_or_else(|| format!("{}: three finite numbers expected", key("xyz")))?;
        let obs = p
            .get("observations")
            .and_then(|o| o.as_array())
            .ok_or_else(|| format!("{}: missing or not a list", key("observations")))?;
        let mut observations = Vec::with_capacity(obs.len());
        for (j, o) in obs.iter().enumerate() {
            let file = o.get("file_path").and_then(|f| f.as_str());
            let px = o
                .get("px")
                .and_then(|v| v.as_array())
                .filter(|a| a.len() == 2)
                .and_then(|a| Some([a[0].as_f64()?, a[1].as_f64()?]))
                .filter(|v| v.iter().all(|c| c.is_finite()));
            match (file, px) {
                (Some(f), Some(px)) => observations.push((f.to_string(), px)),
                _ => return Err(format!("{}[{j}]: needs `file_path` and `px` [x, y]", key("observations"))),
            }
        }
        points.push(ControlPoint { name: name.to_string(), xyz, observations });
    }
    Ok(Some(GroundControl { crs: crs.to_string(), points }))
}

/// A control point placed in the model's frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Placed {
    pub name: String,
    /// Surveyed, dataset CRS.
    pub xyz: [f64; 3],
    /// Triangulated, model frame.
    #[serde(skip)]
    pub model: [f64; 3],
    pub views: usize,
    /// Mean reprojection error of the views used (pixels).
    pub reprojection_px: f64,
    /// The observations used: (image file stem, pixel).
    #[serde(skip)]
    pub observations: Vec<(String, [f64; 2])>,
}

/// fx, fy, cx, cy and the distortion (k1, k2, k3, k4, p1, p2) of `cam`.
pub fn params(cam: &PoseCamera) -> ([f64; 4], [f64; 6]) {
    let k = |n: &str| cam.keys.iter().find(|(key, _)| *key == n).map_or(0.0, |(_, v)| *v);
    let fx = k("fl_x");
    let fy = if cam.keys.iter().any(|(key, _)| *key == "fl_y") { k("fl_y") } else { fx };
    ([fx, fy, k("cx"), k("cy")], [k("k1"), k("k2"), k("k3"), k("k4"), k("p1"), k("p2")])
}

/// The ray of pixel `px` (the image's corner at 0) of `im`: origin and unit direction in the model's frame.
pub fn pixel_ray(im: &PosedImage, px: [f64; 2]) -> ([f64; 3], [f64; 3]) {
    let ([fx, fy, cx, cy], dist) = params(&im.camera);
    let (x, y) = crate::data::camera::undistort((px[0] - cx) / fx, (px[1] - cy) / fy, &dist);
    let d_cam = [x, -y, -1.0];
    let m = &im.c2w;
    let d: [f64; 3] = std::array::from_fn(|i| m[i][0] * d_cam[0] + m[i][1] * d_cam[1] + m[i][2] * d_cam[2]);
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    ([m[0][3], m[1][3], m[2][3]], d.map(|c| c / n))
}

/// Where a model-frame point lands in `im` (the image's corner at 0), or None behind the camera.
pub fn project(im: &PosedImage, p: [f64; 3]) -> Option<[f64; 2]> {
    let ([fx, fy, cx, cy], dist) = params(&im.camera);
    let m = &im.c2w;
    let c = [p[0] - m[0][3], p[1] - m[1][3], p[2] - m[2][3]];
    let cam: [f64; 3] = std::array::from_fn(|j| (0..3).map(|i| m[i][j] * c[i]).sum::<f64>());
    let z = -cam[2];
    if z <= 0.0 {
        return None;
    }
    let (xd, yd) = crate::data::camera::distort(cam[0] / z, -cam[1] / z, &dist);
    Some([fx * xd + cx, fy * yd + cy])
}

/// The point nearest (least squares) to the rays; None when they are parallel.
pub fn nearest_to_rays(rays: &[([f64; 3], [f64; 3])]) -> Option<[f64; 3]> {
    let mut a = vec![0.0; 9];
    let mut b = vec![0.0; 3];
    for (o, d) in rays {
        for i in 0..3 {
            for j in 0..3 {
                let p = f64::from(u8::from(i == j)) - d[i] * d[j];
                a[i * 3 + j] += p;
                b[i] += p * o[j];
            }
        }
    }
    let x = crate::maths::linear::solve(a, b)?;
    Some([x[0], x[1], x[2]])
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0).acos().to_degrees()
}

/// Places every point of `gc` in the model's frame from the observations in the model's registered images (matched
/// by file stem). Returns the placed points and, for each observation or point left out, a note naming it.
pub fn place(model: &PoseModel, gc: &GroundControl) -> (Vec<Placed>, Vec<String>) {
    let by_stem: HashMap<String, &PosedImage> = model.images.iter().map(|im| (stem(&im.name), im)).collect();
    let mut placed = Vec::new();
    let mut notes = Vec::new();
    for p in &gc.points {
        let mut obs: Vec<(&PosedImage, [f64; 2], &str)> = Vec::new();
        for (file, px) in &p.observations {
            match by_stem.get(&stem(file)) {
                Some(im) => obs.push((im, *px, file)),
                None => {
                    notes.push(format!("point {}: frame {file} is not registered; its observation is unused", p.name))
                }
            }
        }
        let solve = |obs: &[(&PosedImage, [f64; 2], &str)]| {
            let rays: Vec<_> = obs.iter().map(|(im, px, _)| pixel_ray(im, *px)).collect();
            let widest = rays
                .iter()
                .enumerate()
                .flat_map(|(i, a)| rays[i + 1..].iter().map(move |b| angle_deg(a.1, b.1)))
                .fold(0.0, f64::max);
            if widest < MIN_ANGLE_DEG {
                return None;
            }
            let x = nearest_to_rays(&rays)?;
            let errs: Vec<f64> = obs
                .iter()
                .map(|(im, px, _)| project(im, x).map_or(f64::INFINITY, |q| (q[0] - px[0]).hypot(q[1] - px[1])))
                .collect();
            Some((x, errs))
        };
        let mut result = solve(&obs);
        // One mis-click at most per round, the worst first, while three views would remain.
        while let Some((_, errs)) = &result {
            let (worst, e) = errs.iter().enumerate().fold((0, 0.0), |a, (i, &e)| if e > a.1 { (i, e) } else { a });
            if e <= MAX_REPROJECTION_PX || obs.len() <= 2 {
                break;
            }
            notes.push(format!(
                "point {}: its pixel in {} is {e:.1} px from where the other views place it; dropped",
                p.name, obs[worst].2
            ));
            obs.remove(worst);
            result = solve(&obs);
        }
        match result {
            Some((x, errs)) if errs.iter().all(|e| *e <= MAX_REPROJECTION_PX) => placed.push(Placed {
                name: p.name.clone(),
                xyz: p.xyz,
                model: x,
                views: obs.len(),
                reprojection_px: errs.iter().sum::<f64>() / errs.len() as f64,
                observations: obs.iter().map(|(_, px, file)| (stem(file), *px)).collect(),
            }),
            Some((_, errs)) => notes.push(format!(
                "point {}: its {} views disagree ({:.1} px reprojection error); not used",
                p.name,
                obs.len(),
                errs.iter().sum::<f64>() / errs.len() as f64
            )),
            None => notes.push(format!(
                "point {}: {} registered view(s) whose rays meet at under {MIN_ANGLE_DEG} degrees; not used",
                p.name,
                obs.len()
            )),
        }
    }
    (placed, notes)
}
