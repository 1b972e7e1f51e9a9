//! The nadir camera pose of a GPS pose prior (positions come from [`crate::geo::Projector`]).

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
