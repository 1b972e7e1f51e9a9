//! Pose normalisation for aerial layouts (issue 18). nerfstudio's `poses` centring puts the centre of the unit cube
//! at the cameras' centroid and scales so that the farthest camera sits at 1: for a flight at height H that puts the
//! ground at z ~ -H / radius (-0.97 on the campus scene, -1.74 on ci-small: inside the contracted region), and half
//! of the grid covers the air above the cameras. `aerial` keeps the up axis vertical (the same rotation as `poses`)
//! but fits the cube to the ground the cameras see:
//!
//! 1. ground height z_g: the median height of the points where pairs of optical axes pass closest to each other
//!    (pairs whose axes meet within 5 % of their distance from the cameras, in front of both; at most 20,000 pairs,
//!    every k-th of the n (n - 1) / 2); fewer than 10 such pairs (e.g. a nadir grid flight with parallel axes) -> no aerial normalisation;
//! 2. footprint: the rays through each image's corners and centre cut the plane z = z_g (rays within ~3 degrees of
//!    the horizon are skipped, hits farther than 10 flight heights are clamped); the 2nd-98th percentile box of the
//!    hits in x and y;
//! 3. scale 1 / E with E the larger half-side of that box; centre (box centre, z_g + E / 2), so the ground lies at
//!    z = -0.5 and what stands on it up to 1.5 E is inside the cube.
//!
//! Up is the mean of the cameras' up vectors, as for `poses`: on a flight that mixes nadir images of one heading
//! with obliques, the nadir images tilt it (the same limitation as nerfstudio's `up`).
//!
//! The result is a [`PoseTransform`] like any other (nerfstudio's `dataparser_transforms.json` format).

use super::camera::{camera_direction, Camera};
use super::pose::{rotation_between, Mat4, PoseTransform};
use crate::util::stats::nearest_rank as percentile;
use glam::DVec3;

/// Why the aerial normalisation does not apply (the caller falls back to `poses` and says so).
#[derive(Debug, Clone, PartialEq)]
pub enum NotAerial {
    /// The cameras do not look down on average (mean forward z > -0.25 after levelling).
    NotLookingDown(f64),
    /// Too few optical axes meet to place the ground.
    AxesDoNotMeet(usize),
    /// No image corner or centre ray reaches the ground plane.
    NoGroundInView,
}

impl std::fmt::Display for NotAerial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NotAerial::NotLookingDown(z) => write!(f, "the cameras do not look down (mean forward z {z:.2})"),
            NotAerial::AxesDoNotMeet(n) => {
                write!(f, "only {n} pairs of optical axes meet, too few to place the ground (a nadir flight?)")
            }
            NotAerial::NoGroundInView => write!(f, "no image ray reaches the estimated ground plane"),
        }
    }
}

/// Column `c` of a 4x4 pose (rows) as a vector.
fn column(p: &Mat4, c: usize) -> DVec3 {
    DVec3::new(p[0][c], p[1][c], p[2][c])
}

/// The ground the cameras see, in the levelled world frame (the world turned so that the cameras' mean up is +z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundFootprint {
    /// World -> levelled frame.
    pub rotation: glam::DMat3,
    /// Ground height z_g (levelled frame, world units).
    pub ground_z: f64,
    /// Mean camera height above the ground.
    pub height: f64,
    /// The 2nd-98th percentile box of where image corner and centre rays meet the ground: x0, x1, y0, y1.
    pub bounds: [f64; 4],
}

/// The aerial normalisation of cameras `frames` (camera-to-world, intrinsics).
pub fn normalize_poses_aerial(frames: &[(Mat4, Camera)]) -> Result<PoseTransform, NotAerial> {
    let g = ground_footprint(frames)?;
    let [x0, x1, y0, y1] = g.bounds;
    // 3. Scale and centre.
    let e = (0.5 * (x1 - x0)).max(0.5 * (y1 - y0)).max(0.25 * g.height.abs()).max(1e-9);
    let centre = DVec3::new(0.5 * (x0 + x1), 0.5 * (y0 + y1), g.ground_z + 0.5 * e);
    Ok(PoseTransform::new(g.rotation, -centre, 1.0 / e))
}

/// Steps 1 and 2 of the aerial normalisation: the ground height and the footprint of the views on it.
pub fn ground_footprint(frames: &[(Mat4, Camera)]) -> Result<GroundFootprint, NotAerial> {
    ground_footprint_with(frames, None, None)
}

/// [`ground_footprint`] with the levelling given (`rotation`, world -> levelled; e.g. the identity for a projected
/// CRS, whose z is up; default: the cameras' mean up turned to +z) and the ground height given (`ground_z`, levelled
/// frame; default: where the optical axes meet, which needs axes that are not parallel).
pub fn ground_footprint_with(
    frames: &[(Mat4, Camera)],
    rotation: Option<glam::DMat3>,
    ground_z: Option<f64>,
) -> Result<GroundFootprint, NotAerial> {
    let n = frames.len();
    let up = frames.iter().fold(DVec3::ZERO, |u, (p, _)| u + column(p, 1));
    let r = rotation.unwrap_or_else(|| rotation_between(up, DVec3::Z));
    // Levelled camera centres and forward axes (OpenGL cameras look along -z).
    let centres: Vec<DVec3> = frames.iter().map(|(p, _)| r * column(p, 3)).collect();
    let fwd: Vec<DVec3> = frames.iter().map(|(p, _)| r * -column(p, 2)).collect();
    let mean_fz = fwd.iter().map(|a| a.z).sum::<f64>() / n.max(1) as f64;
    if mean_fz.is_nan() || mean_fz >= -0.25 {
        return Err(NotAerial::NotLookingDown(mean_fz));
    }
    // 1. Where pairs of optical axes meet (unless the ground height is given).
    let z_g = match ground_z {
        Some(z) => z,
        None => axes_meet_height(&centres, &fwd)?,
    };
    // 2. The footprint on z = z_g.
    let height = centres.iter().map(|c| c.z - z_g).sum::<f64>() / n as f64;
    let max_reach = 10.0 * height.abs().max(1e-9);
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for ((p, cam), c) in frames.iter().zip(&centres) {
        let k = cam.intrinsics::<f64>();
        let (w, h) = (cam.width as f64, cam.height as f64);
        for (v, u) in [(0.0, 0.0), (0.0, w), (h, 0.0), (h, w), (0.5 * h, 0.5 * w)] {
            let dc = DVec3::from(camera_direction(&k, v, u));
            let d = r * (column(p, 0) * dc.x + column(p, 1) * dc.y + column(p, 2) * dc.z);
            if d.z.is_nan() || d.z >= -0.05 * d.length() {
                continue;
            }
            // Where the ray meets z = z_g, its horizontal reach clamped to max_reach.
            let hit = (d * ((z_g - c.z) / d.z)).truncate().clamp_length_max(max_reach);
            xs.push(c.x + hit.x);
            ys.push(c.y + hit.y);
        }
    }
    if xs.is_empty() {
        return Err(NotAerial::NoGroundInView);
    }
    let (x0, x1) = (percentile(&mut xs, 0.02), percentile(&mut xs, 0.98));
    let (y0, y1) = (percentile(&mut ys, 0.02), percentile(&mut ys, 0.98));
    Ok(GroundFootprint { rotation: r, ground_z: z_g, height, bounds: [x0, x1, y0, y1] })
}

/// The median height where pairs of optical axes pass within 5 % of their distance of each other.
fn axes_meet_height(centres: &[DVec3], fwd: &[DVec3]) -> Result<f64, NotAerial> {
    let n = centres.len();
    let pairs = n * (n.saturating_sub(1)) / 2;
    let stride = pairs.div_ceil(20_000).max(1);
    let mut meet_z = Vec::new();
    let mut k = 0usize;
    for i in 0..n {
        for j in i + 1..n {
            k += 1;
            if k % stride != 0 {
                continue;
            }
            let (c1, a1, c2, a2) = (centres[i], fwd[i], centres[j], fwd[j]);
            let w = c1 - c2;
            let (b, d, e) = (a1.dot(a2), a1.dot(w), a2.dot(w));
            let den = 1.0 - b * b;
            if den < 0.0076 {
                continue; // axes within 5 degrees of parallel
            }
            let (s, t) = ((b * e - d) / den, (e - b * d) / den);
            if s <= 0.0 || t <= 0.0 {
                continue;
            }
            let (p1, p2) = (c1 + s * a1, c2 + t * a2);
            if p1.distance(p2) < 0.05 * s.min(t) {
                meet_z.push(0.5 * (p1.z + p2.z));
            }
        }
    }
    if meet_z.len() < 10 {
        return Err(NotAerial::AxesDoNotMeet(meet_z.len()));
    }
    Ok(percentile(&mut meet_z, 0.5))
}
