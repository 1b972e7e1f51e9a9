//! Simulated SfM points (`--sparse-points N`): what a structure-from-motion run leaves for depth supervision, made
//! from the simulator's truth. Each view seeds points at random pixels with a surface (its depth map gives the 3-D
//! point); a point's track is every view whose own depth map sees it (the reprojected pixel's depth agrees within 1 %
//! of the distance): visibility, as a feature matcher would find it. Points seen by fewer than `min_views` views
//! are dropped, as SfM drops short tracks. With `noise_m` > 0 each point moves by isotropic Gaussian noise (metres),
//! and its `error` is the mean reprojection error over its track in pixels, as COLMAP reports it.

use super::render::Prepared;
use crate::data::camera::{project_point, project_point_subpixel};
use crate::data::sparse_points::{write_sparse_points, NamedPoint};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// How many points and how noisy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparseOptions {
    /// Target number of points over the whole dataset (fewer when tracks are too short).
    pub count: usize,
    /// Standard deviation of the position noise, metres.
    pub noise_m: f64,
    /// Shortest track kept.
    pub min_views: usize,
}

/// Relative depth agreement for a view to count as observing a point.
const VISIBLE_TOLERANCE: f64 = 0.01;

fn rot_origin(m: &[[f64; 4]; 4]) -> ([[f64; 3]; 3], [f64; 3]) {
    ([0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]), [m[0][3], m[1][3], m[2][3]])
}

/// The tracks: points in the local frame (noise applied) with their views and reprojection errors.
pub fn make_tracks(prep: &Prepared, depths: &[Vec<f32>], o: &SparseOptions) -> Vec<([f64; 3], Vec<usize>, f64)> {
    let cam = &prep.camera;
    let (w, h) = (cam.width, cam.height);
    let nv = prep.poses.len();
    let mut rng = ChaCha8Rng::seed_from_u64(prep.seed ^ 0x5fa5_e0f7);
    let per_view = o.count.div_ceil(nv.max(1));
    let cams: Vec<_> = prep.poses.iter().map(rot_origin).collect();
    let mut out = Vec::new();
    for (i, depth) in depths.iter().enumerate() {
        for _ in 0..per_view {
            let (row, col) = (rng.random_range(0..h), rng.random_range(0..w));
            let d = depth[(row * w + col) as usize] as f64;
            if !(d > 0.0 && d.is_finite()) {
                continue;
            }
            let ray = cam.ray_f64(&prep.poses[i], row, col);
            let p: [f64; 3] = [0, 1, 2].map(|k| ray.origin[k] + d * ray.direction[k]);
            let views: Vec<usize> = (0..nv)
                .filter(|&j| {
                    let (rot, origin) = &cams[j];
                    project_point(cam, *origin, rot, p).is_some_and(|(r, c, dist)| {
                        let dj = depths[j][(r * w + c) as usize] as f64;
                        (dj - dist).abs() <= VISIBLE_TOLERANCE * dist
                    })
                })
                .collect();
            if views.len() < o.min_views.max(1) || !views.contains(&i) {
                continue;
            }
            let noisy = if o.noise_m > 0.0 {
                let mut g = || {
                    // Box-Muller: a standard normal from two uniforms.
                    let (u1, u2): (f64, f64) = (rng.random_range(f64::EPSILON..1.0), rng.random());
                    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                };
                [p[0] + o.noise_m * g(), p[1] + o.noise_m * g(), p[2] + o.noise_m * g()]
            } else {
                p
            };
            // Reprojection error of the noisy point against where the true point is seen, in pixels.
            let (mut err, mut m) = (0.0, 0usize);
            let mut track = Vec::with_capacity(views.len());
            for &j in &views {
                let (rot, origin) = &cams[j];
                let sub = |q| project_point_subpixel(cam, *origin, rot, q);
                let (Some(a), Some(b)) = (sub(p), sub(noisy)) else {
                    continue; // the noise pushed it out of this view: not in its track
                };
                err += ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
                m += 1;
                track.push(j);
            }
            if track.len() >= o.min_views.max(1) {
                out.push((noisy, track, err / m as f64));
            }
        }
    }
    out
}

/// Writes `sparse_points.json` in `root`: world coordinates (local + `world_offset`), frames named as
/// `transforms.json` names them (`names[view]`). Returns the number of points.
pub fn write(
    prep: &Prepared,
    root: &Path,
    tracks: &[([f64; 3], Vec<usize>, f64)],
    names: &[String],
) -> Result<usize, crate::util::atomic::WriteError> {
    let o = prep.world_offset;
    let pts: Vec<NamedPoint> = tracks
        .iter()
        .map(|(p, views, err)| NamedPoint {
            xyz: [p[0] + o[0], p[1] + o[1], p[2] + o[2]],
            error: Some(*err),
            frames: views.iter().map(|&j| names[j].clone()).collect(),
        })
        .collect();
    write_sparse_points(&root.join("sparse_points.json"), &pts)?;
    Ok(pts.len())
}
