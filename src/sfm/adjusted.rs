//! The bundle adjustment ([`super::bundle`]) run on `msnerf sfm`'s georeferenced model when the dataset has ground
//! control: the problem built from the model (cameras, COLMAP's tie points with their pixels, the placed control
//! points with the clicks kept by [`super::control::place`], the GPS fixes), the result written back (poses, tie
//! points and their reprojection errors), and the control points measured again as Metashape reports them: each
//! point's residual (triangulated from the adjusted cameras minus surveyed) and its check residual (the adjustment
//! run again without the point, then the point triangulated from those cameras).
//!
//! The GPS fixes enter the adjustment only when fewer than [`CONTROL_FIXES_FRAME`] control points are placed: three
//! points fix the frame, and fixes with a metre of noise then add nothing to the flight's shape while they pull
//! on its weak modes (a camera's shift traded against its tilt: tests/data/sfm_bundle.rs measures it). The
//! datum shift is then the fixes' mean offset from the adjusted centres.

use std::collections::HashMap;

use super::bundle::{self, Camera, Observation, Problem, Solution};
use super::control::{nearest_to_rays, params, pixel_ray, Placed};
use super::georef::{ControlResidual, CONTROL_SIGMA_M};
use crate::poses::apply::stem;
use crate::poses::colmap::ColmapModel;
use crate::poses::model::{c2w_from_w2c_opencv, PoseModel};

/// Control points from which the GPS fixes are left out of the adjustment.
pub const CONTROL_FIXES_FRAME: usize = 3;

/// What the adjustment did, for the sfm report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AdjustmentReport {
    pub iterations: usize,
    pub observations: usize,
    /// RMS reprojection error of the tie points and clicks before and after (pixels).
    pub rms_px_before: f64,
    pub rms_px_after: f64,
    /// The similarity's control residual RMS and check RMS before the adjustment (metres), for comparison.
    pub similarity_rms_m: f64,
    pub similarity_check_rms_m: Option<f64>,
    pub seconds: f64,
}

fn camera_of(im: &crate::poses::model::PosedImage) -> Camera {
    let (intrinsics, distortion) = params(&im.camera);
    let m = &im.c2w;
    // OpenCV world-to-camera: diag(1, -1, -1) R_c2w^T.
    let r = std::array::from_fn(|i| std::array::from_fn(|j| if i == 0 { m[j][i] } else { -m[j][i] }));
    Camera { r, c: [m[0][3], m[1][3], m[2][3]], intrinsics, distortion }
}

/// The problem for `model` (georeferenced) and the COLMAP model it came from (same image ids, same point order):
/// `gps` are (model image index, fix) pairs, `control` the placed points (each a point after the tie points).
fn build(
    model: &PoseModel,
    cm: &ColmapModel,
    gps: &[(usize, [f64; 3])],
    gps_sigma: f64,
    control: &[&Placed],
) -> Result<Problem, String> {
    let index: HashMap<u64, usize> = model.images.iter().enumerate().map(|(i, im)| (im.id, i)).collect();
    let cm_images: HashMap<u32, &crate::poses::colmap::ColmapImage> = cm.images.iter().map(|im| (im.id, im)).collect();
    let mut p = Problem {
        cameras: model.images.iter().map(camera_of).collect(),
        centre_priors: if control.len() >= CONTROL_FIXES_FRAME { Vec::new() } else { gps.to_vec() },
        centre_sigma: gps_sigma,
        ..Problem::default()
    };
    if cm.points.len() != model.points.len() {
        return Err(format!("the model has {} points, COLMAP's {}", model.points.len(), cm.points.len()));
    }
    for (j, pt) in cm.points.iter().enumerate() {
        p.points.push(model.points[j].xyz);
        for (&id, &k) in pt.images.iter().zip(&pt.point2d) {
            let (Some(&camera), Some(im)) = (index.get(&u64::from(id)), cm_images.get(&id)) else { continue };
            let px = *im
                .points2d
                .get(k as usize)
                .ok_or_else(|| format!("point {}: image {} has no 2-D point {k}", pt.id, im.name))?;
            p.observations.push(Observation { camera, point: j, px });
        }
    }
    let by_stem: HashMap<String, usize> = model.images.iter().enumerate().map(|(i, im)| (stem(&im.name), i)).collect();
    for c in control {
        let j = p.points.len();
        p.points.push(c.model);
        p.point_priors.push((j, c.xyz, CONTROL_SIGMA_M));
        for (s, px) in &c.observations {
            if let Some(&camera) = by_stem.get(s) {
                p.observations.push(Observation { camera, point: j, px: *px });
            }
        }
    }
    Ok(p)
}

fn write_back(model: &mut PoseModel, s: &Solution) {
    for (im, c) in model.images.iter_mut().zip(&s.cameras) {
        let t: [f64; 3] = std::array::from_fn(|i| -(0..3).map(|k| c.r[i][k] * c.c[k]).sum::<f64>());
        im.c2w = c2w_from_w2c_opencv(c.r, t);
    }
    for (p, x) in model.points.iter_mut().zip(&s.points) {
        p.xyz = *x;
    }
}

/// The point triangulated from `model`'s cameras with `c`'s clicks, minus its surveyed position.
fn residual(model: &PoseModel, c: &Placed) -> Option<[f64; 3]> {
    let by_stem: HashMap<String, &crate::poses::model::PosedImage> =
        model.images.iter().map(|im| (stem(&im.name), im)).collect();
    let rays: Vec<_> =
        c.observations.iter().filter_map(|(s, px)| by_stem.get(s).map(|im| pixel_ray(im, *px))).collect();
    let x = nearest_to_rays(&rays)?;
    Some([x[0] - c.xyz[0], x[1] - c.xyz[1], x[2] - c.xyz[2]])
}

/// The adjustment's outcome: its report, the control points measured on the adjusted cameras, and the GPS's
/// datum shift (fix minus adjusted centre, east, north, up) when there are fixes.
pub struct Adjusted {
    pub report: AdjustmentReport,
    pub points: Vec<ControlResidual>,
    pub gps_shift_m: Option<[f64; 3]>,
}

/// Adjusts `model` (already on the similarity `super::georef` fitted) on its tie points, `control` and the `gps`
/// fixes (model image index, projected fix). `model`'s poses and points are replaced.
pub fn adjust_with_control(
    model: &mut PoseModel,
    cm: &ColmapModel,
    gps: &[(usize, [f64; 3])],
    gps_sigma: f64,
    control: &[Placed],
) -> Result<Adjusted, String> {
    let t0 = std::time::Instant::now();
    let all: Vec<&Placed> = control.iter().collect();
    let problem = build(model, cm, gps, gps_sigma, &all)?;
    let sol = bundle::adjust(&problem)?;
    let before = model.clone();
    write_back(model, &sol);
    // Tie points' reprojection errors on the adjusted cameras.
    let mut err = vec![(0.0, 0usize); model.points.len()];
    for o in problem.observations.iter().filter(|o| o.point < model.points.len()) {
        if let Some(q) = bundle::project(&sol.cameras[o.camera], sol.points[o.point]) {
            err[o.point].0 += (q[0] - o.px[0]).hypot(q[1] - o.px[1]);
            err[o.point].1 += 1;
        }
    }
    for (p, (s, n)) in model.points.iter_mut().zip(err) {
        if n > 0 {
            p.error = Some(s / n as f64);
        }
    }
    let mut points = Vec::with_capacity(control.len());
    for (k, c) in control.iter().enumerate() {
        let others: Vec<&Placed> = control.iter().enumerate().filter(|(i, _)| *i != k).map(|(_, c)| c).collect();
        let check = if others.is_empty() && gps.len() < 3 {
            None
        } else {
            let b = build(&before, cm, gps, gps_sigma, &others)?;
            let s = bundle::adjust(&b)?;
            let mut m = before.clone();
            write_back(&mut m, &s);
            residual(&m, c)
        };
        points.push(ControlResidual {
            name: c.name.clone(),
            views: c.views,
            reprojection_px: c.reprojection_px,
            residual_m: residual(model, c).ok_or_else(|| format!("control point {}: its rays are parallel", c.name))?,
            check_m: check,
        });
    }
    let report = AdjustmentReport {
        iterations: sol.iterations,
        observations: problem.observations.len(),
        rms_px_before: sol.rms_px_before,
        rms_px_after: sol.rms_px_after,
        similarity_rms_m: 0.0,
        similarity_check_rms_m: None,
        seconds: t0.elapsed().as_secs_f64(),
    };
    let offset = if gps.is_empty() {
        None
    } else if problem.centre_priors.is_empty() {
        let n = gps.len() as f64;
        Some(std::array::from_fn(|k| gps.iter().map(|(i, f)| f[k] - sol.cameras[*i].c[k]).sum::<f64>() / n))
    } else {
        Some(sol.gps_offset)
    };
    Ok(Adjusted { report, points, gps_shift_m: offset })
}
