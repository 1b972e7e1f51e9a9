//! Camera poses built from a position and a direction, shared by the simulator's cameras, novel views
//! (`nerf::views`) and the GPS pose priors of a raw import: camera-to-world 4x4 matrices with OpenGL camera axes
//! (+x right, +y up, looking along -z), the convention of `transforms.json`. A heading h is horizontal; a camera
//! with gimbal tilt t looks along f = (cos t h, sin t) (-90 degrees = nadir), right = h x z, up = right x f, so at
//! nadir the image top points along h.

use glam::{DMat4, DVec3};

use super::pose::{from_dmat4, Mat4};

fn norm(v: DVec3) -> DVec3 {
    v / v.length()
}

/// The camera-to-world pose with these axes: columns right, up, −forward (OpenGL cameras look along −z), position.
fn from_axes(pos: DVec3, right: DVec3, up: DVec3, fwd: DVec3) -> Mat4 {
    from_dmat4(&DMat4::from_cols(right.extend(0.0), up.extend(0.0), (-fwd).extend(0.0), pos.extend(1.0)))
}

/// Pose at `pos` with horizontal unit heading `h` = (hx, hy) and gimbal tilt `tilt_deg`.
pub fn heading_pose(pos: [f64; 3], h: [f64; 2], tilt_deg: f64) -> Mat4 {
    let (st, ct) = tilt_deg.to_radians().sin_cos();
    let fwd = norm(DVec3::new(ct * h[0], ct * h[1], st));
    let right = DVec3::new(h[1], -h[0], 0.0);
    let up = right.cross(fwd);
    from_axes(pos.into(), right, up, fwd)
}

/// Pose at `pos` looking at `target` with `up` hint (+z when `None`; +y when looking straight along it).
pub fn look_at(pos: [f64; 3], target: [f64; 3], up: Option<[f64; 3]>) -> Mat4 {
    let pos = DVec3::from(pos);
    let fwd = norm(DVec3::from(target) - pos);
    let mut hint = up.map_or(DVec3::Z, DVec3::from);
    if fwd.cross(hint).length_squared() < 1e-12 {
        hint = DVec3::Y;
    }
    let right = norm(fwd.cross(hint));
    let upv = right.cross(fwd);
    from_axes(pos, right, upv, fwd)
}

/// Camera-to-world (OpenGL axes, row-major 4x4) of a nadir camera at `pos` whose image top points to
/// `heading_deg` (clockwise from north).
pub fn nadir_pose(pos: [f64; 3], heading_deg: f64) -> [[f64; 4]; 4] {
    let (s, c) = heading_deg.to_radians().sin_cos();
    // Columns: camera x (image right), y (image up), z (back, = world up for a nadir view).
    let x = [c, -s, 0.0];
    let y = [s, c, 0.0];
    let z = [0.0, 0.0, 1.0];
    [[x[0], y[0], z[0], pos[0]], [x[1], y[1], z[1], pos[1]], [x[2], y[2], z[2], pos[2]], [0.0, 0.0, 0.0, 1.0]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The import's nadir pose is the tilted pose at -90 degrees with the heading as the image top.
    #[test]
    fn nadir_is_the_heading_pose_looking_down() {
        for heading in [0.0f64, 37.0, 90.0, 200.0, 315.5] {
            let (s, c) = heading.to_radians().sin_cos();
            let a = nadir_pose([1.0, 2.0, 3.0], heading);
            let b = heading_pose([1.0, 2.0, 3.0], [s, c], -90.0);
            for i in 0..4 {
                for j in 0..4 {
                    assert!((a[i][j] - b[i][j]).abs() < 1e-12, "heading {heading}: {a:?} vs {b:?}");
                }
            }
        }
    }
}
