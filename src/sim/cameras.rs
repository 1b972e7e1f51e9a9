//! Camera poses (orbit rings, lawnmower grids, explicit poses) and pinhole intrinsics.
//!
//! Poses are camera-to-world 4x4 matrices in the scene's local frame with OpenGL camera axes (+x right, +y up,
//! looking along −z), the convention of `transforms.json`. A view's heading h is horizontal; the camera looks
//! along f = (cos τ · h, sin τ) for gimbal tilt τ (−90° = nadir), right = h × z, up = right × f, so at nadir
//! the image top points along h.
//!
//! - orbit: view i at azimuth a = start + 360°·i/count (counter-clockwise from east) on the circle, heading
//!   towards the centre.
//! - grid: rows along the heading (`heading_deg`, clockwise from north), columns across it, serpentine order.
//! - poses: `position` + `look_at` (+ `up`, default +z), or a `transform_matrix`.
//!
//! Intrinsics: fx = fy = (w/2) / tan(HFOV/2), principal point at the image centre (w/2, h/2).

use crate::data::camera::{Camera, CameraModel, Distortion};
pub use crate::data::pose::Mat4;
pub use crate::data::pose_build::{heading_pose, look_at};

use super::scene::{CameraGroupDesc, SceneDesc};

/// Pinhole intrinsics for a `width` x `height` image with horizontal field of view `hfov_deg`.
pub fn intrinsics(width: u32, height: u32, hfov_deg: f64) -> Camera {
    let f = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
    Camera {
        model: CameraModel::Pinhole,
        fx: f,
        fy: f,
        cx: width as f64 / 2.0,
        cy: height as f64 / 2.0,
        width,
        height,
        distortion: Distortion::default(),
    }
}

/// Per-group view counts, with `views` (if given) spread over the orbit groups (exactly) or the grid groups
/// (rows and cols scaled, approximately). Explicit poses keep their count.
fn group_counts(groups: &[CameraGroupDesc], views: Option<usize>) -> Result<Vec<(usize, usize)>, String> {
    // (count, or for grids (rows, cols)); orbits use .0 only.
    let natural: Vec<(usize, usize)> = groups
        .iter()
        .map(|g| match (&g.orbit, &g.grid, &g.poses) {
            (Some(o), _, _) => (o.count, 1),
            (_, Some(gr), _) => (gr.rows, gr.cols),
            (_, _, Some(p)) => (p.len(), 1),
            _ => (0, 1),
        })
        .collect();
    let Some(n) = views else { return Ok(natural) };
    if n == 0 {
        return Err("must be at least 1".into());
    }
    let fixed: usize = groups.iter().zip(&natural).filter(|(g, _)| g.poses.is_some()).map(|(_, c)| c.0).sum();
    let orbits: Vec<usize> = (0..groups.len()).filter(|&i| groups[i].orbit.is_some()).collect();
    let grids: Vec<usize> = (0..groups.len()).filter(|&i| groups[i].grid.is_some()).collect();
    let mut out = natural.clone();
    if !orbits.is_empty() {
        let grid_n: usize = grids.iter().map(|&i| natural[i].0 * natural[i].1).sum();
        let budget = n.checked_sub(fixed + grid_n).filter(|&b| b >= orbits.len()).ok_or_else(|| {
            format!("{n} views leave fewer than one per orbit after {} fixed grid/pose views", fixed + grid_n)
        })?;
        let total: usize = orbits.iter().map(|&i| natural[i].0).sum();
        let mut left = budget;
        for (k, &i) in orbits.iter().enumerate() {
            let c = if k + 1 == orbits.len() {
                left
            } else {
                ((budget * natural[i].0) as f64 / total as f64).round().max(1.0) as usize
            };
            let c = c.min(left - (orbits.len() - k - 1));
            out[i].0 = c;
            left -= c;
        }
        return Ok(out);
    }
    if !grids.is_empty() {
        let grid_n: usize = grids.iter().map(|&i| natural[i].0 * natural[i].1).sum();
        let target = n.saturating_sub(fixed).max(grids.len());
        let s = (target as f64 / grid_n as f64).sqrt();
        for &i in &grids {
            out[i] = (
                ((natural[i].0 as f64 * s).round() as usize).max(1),
                ((natural[i].1 as f64 * s).round() as usize).max(1),
            );
        }
        return Ok(out);
    }
    Err("the scene has only explicit poses; their number cannot change".into())
}

/// All views of the scene, in order, local frame.
pub fn scene_poses(d: &SceneDesc, views: Option<usize>) -> Result<Vec<Mat4>, String> {
    if let Some(v) = views.filter(|&v| v > super::scene::MAX_VIEWS) {
        return Err(format!("{v} views: at most {}", super::scene::MAX_VIEWS));
    }
    let counts = group_counts(&d.cameras, views)?;
    let mut out = Vec::new();
    for (g, &(n, m)) in d.cameras.iter().zip(&counts) {
        if let Some(o) = &g.orbit {
            for i in 0..n {
                let a = (o.start_deg + 360.0 * i as f64 / n as f64).to_radians();
                let (s, c) = a.sin_cos();
                let pos = [o.center[0] + o.radius * c, o.center[1] + o.radius * s, o.height];
                out.push(heading_pose(pos, [-c, -s], o.tilt_deg));
            }
        } else if let Some(gr) = &g.grid {
            let (rows, cols) = (n, m);
            let (s, c) = gr.heading_deg.to_radians().sin_cos();
            let h = [s, c];
            let right = [c, -s];
            let step = |size: f64, k: usize| if k > 1 { size / (k - 1) as f64 } else { 0.0 };
            let (dr, dc) = (step(gr.size[1], rows), step(gr.size[0], cols));
            for r in 0..rows {
                for k in 0..cols {
                    let kk = if r % 2 == 0 { k } else { cols - 1 - k };
                    let a = dr * r as f64 - gr.size[1] / 2.0 * (rows > 1) as u8 as f64;
                    let b = dc * kk as f64 - gr.size[0] / 2.0 * (cols > 1) as u8 as f64;
                    let pos =
                        [gr.center[0] + a * h[0] + b * right[0], gr.center[1] + a * h[1] + b * right[1], gr.height];
                    out.push(heading_pose(pos, h, gr.tilt_deg));
                }
            }
        } else if let Some(p) = &g.poses {
            for q in p {
                match (q.position, q.look_at, q.transform_matrix) {
                    (Some(pos), Some(t), _) => out.push(look_at(pos, t, q.up)),
                    (_, _, Some(m)) => out.push(m),
                    _ => return Err("pose needs position + look_at or transform_matrix".into()),
                }
            }
        }
    }
    Ok(out)
}
