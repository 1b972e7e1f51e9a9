//! Novel views (cameras that are not dataset frames) and the orbit `msnerf render --views orbit` draws: N cameras
//! on a circle around the training cameras' look-at centre, all looking at it, with the first frame's intrinsics.
//!
//! Everything is computed in the normalised training frame, where +Z is the cameras' mean up (nerfstudio's
//! orientation "up", spec/nerfacto.md §2.1), so "height" and "pitch" mean the same for every dataset. Radius and
//! height given by the user are in the dataset's world units and are scaled into that frame.
//! Defaults: centre = the least-squares point closest to the training cameras' optical axes (nerfstudio's "focus"
//! centre); radius = their mean horizontal distance from it; height = their mean height above it.

use super::error::{NerfError, NerfResult};
use crate::data::pose::Mat4;
use crate::data::pose_build::{heading_pose, look_at};
use crate::data::{Camera, Dataset, PoseTransform, Split};

/// A camera to render that is not a dataset frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NovelView {
    /// Output file stem, e.g. `orbit_003`.
    pub name: String,
    /// Intrinsics; `width` x `height` is the rendered size.
    pub camera: Camera,
    /// Camera-to-world (OpenGL axes) in the normalised training frame.
    pub c2w: Mat4,
}

/// The orbit's shape; `None` fields take the defaults derived from the training cameras.
#[derive(Clone, Debug, PartialEq)]
pub struct OrbitDesc {
    pub views: usize,
    /// Horizontal distance from the centre, world units.
    pub radius: Option<f64>,
    /// Height above the centre, world units.
    pub height: Option<f64>,
    /// Camera pitch in degrees (negative looks down). Alone, it sets the height so that the cameras still look at
    /// the centre; with `height` as well, the cameras keep that pitch and face the centre horizontally.
    pub pitch_deg: Option<f64>,
}

/// The circle the orbit defaults to, in the normalised frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitFrame {
    pub centre: [f64; 3],
    pub radius: f64,
    pub height: f64,
    /// Angle (radians, about +Z from +X) of the first training camera around the centre: `orbit_000` starts there.
    pub start_angle: f64,
}

fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.abs() < 1e-9 {
        return None;
    }
    // Cramer's rule.
    Some([0, 1, 2].map(|k| {
        let mut m = a;
        for (r, row) in m.iter_mut().enumerate() {
            row[k] = b[r];
        }
        det(m) / d
    }))
}

/// The default orbit of the training cameras (normalised poses). With parallel optical axes (a nadir grid) there is
/// no closest point: the centre is then one normalised unit (the camera spread) along the mean viewing direction.
pub fn orbit_frame(poses: &[Mat4]) -> NerfResult<OrbitFrame> {
    if poses.is_empty() {
        return Err(NerfError::invalid("orbit", "no training cameras to derive an orbit from"));
    }
    let n = poses.len() as f64;
    let origin = |p: &Mat4| [p[0][3], p[1][3], p[2][3]];
    let axis = |p: &Mat4| {
        let d = [-p[0][2], -p[1][2], -p[2][2]];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|v| v / l)
    };
    let mut a = [[0.0; 3]; 3];
    let mut b = [0.0; 3];
    let (mut mean_o, mut mean_d) = ([0.0; 3], [0.0; 3]);
    for p in poses {
        let (o, d) = (origin(p), axis(p));
        for i in 0..3 {
            mean_o[i] += o[i] / n;
            mean_d[i] += d[i] / n;
            for j in 0..3 {
                let m = if i == j { 1.0 } else { 0.0 } - d[i] * d[j];
                a[i][j] += m;
                b[i] += m * o[j];
            }
        }
    }
    let centre = solve3(a, b).unwrap_or([0, 1, 2].map(|i| mean_o[i] + mean_d[i]));
    let (mut radius, mut height) = (0.0, 0.0);
    for p in poses {
        let o = origin(p);
        radius += ((o[0] - centre[0]).powi(2) + (o[1] - centre[1]).powi(2)).sqrt() / n;
        height += (o[2] - centre[2]) / n;
    }
    let o0 = origin(&poses[0]);
    let start_angle = (o0[1] - centre[1]).atan2(o0[0] - centre[0]);
    Ok(OrbitFrame { centre, radius, height, start_angle })
}

/// The orbit's cameras (`orbit_000` ...), in the normalised frame.
pub fn orbit_views(ds: &Dataset, transform: &PoseTransform, desc: &OrbitDesc) -> NerfResult<Vec<NovelView>> {
    if desc.views == 0 || desc.views > 100_000 {
        return Err(NerfError::invalid("--orbit-views", format!("must be 1..=100000, got {}", desc.views)));
    }
    let check = |flag: &str, v: Option<f64>, ok: &dyn Fn(f64) -> bool, want: &str| match v {
        Some(x) if !x.is_finite() || !ok(x) => Err(NerfError::invalid(flag, format!("must be {want}, got {x}"))),
        _ => Ok(()),
    };
    check("--orbit-radius", desc.radius, &|x| x > 0.0, "positive")?;
    check("--orbit-height", desc.height, &|_| true, "finite")?;
    check("--orbit-pitch-deg", desc.pitch_deg, &|x| x.abs() < 90.0, "strictly between -90 and 90")?;
    let train = ds.split_indices(Split::Train);
    let frames = if train.is_empty() { (0..ds.frames.len()).collect() } else { train };
    let poses: Vec<Mat4> = frames.iter().map(|&f| transform.pose_to_normalized(&ds.frames[f].c2w)).collect();
    let of = orbit_frame(&poses)?;
    let s = transform.scale;
    let radius = desc.radius.map_or(of.radius, |r| r * s);
    if radius <= 0.0 {
        return Err(NerfError::invalid("--orbit-radius", "the training cameras sit on the orbit centre: give one"));
    }
    let height = match (desc.height, desc.pitch_deg) {
        (Some(h), _) => h * s,
        (None, Some(p)) => -radius * p.to_radians().tan(),
        (None, None) => of.height,
    };
    let camera = ds.frames.first().ok_or_else(|| NerfError::file(&ds.root, "the dataset has no frames"))?.camera;
    let c = of.centre;
    let views = (0..desc.views)
        .map(|k| {
            let a = of.start_angle + 2.0 * std::f64::consts::PI * k as f64 / desc.views as f64;
            let (sa, ca) = a.sin_cos();
            let pos = [c[0] + radius * ca, c[1] + radius * sa, c[2] + height];
            let c2w = match (desc.height, desc.pitch_deg) {
                (Some(_), Some(p)) => heading_pose(pos, [-ca, -sa], p),
                _ => look_at(pos, c, Some([0.0, 0.0, 1.0])),
            };
            NovelView { name: format!("orbit_{k:03}"), camera, c2w }
        })
        .collect();
    Ok(views)
}
