//! WGS84 geodetic -> local east-north-up metres about an origin (exact: geodetic -> ECEF -> rotation into the
//! origin's tangent plane). Used for the GPS pose priors of imported captures until poses come from SfM.

const A: f64 = 6_378_137.0;
const F: f64 = 1.0 / 298.257_223_563;

/// Earth-centred, earth-fixed coordinates of a WGS84 position (degrees, metres above the ellipsoid).
pub fn ecef(lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    let e2 = F * (2.0 - F);
    let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
    let n = A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    [(n + h) * lat.cos() * lon.cos(), (n + h) * lat.cos() * lon.sin(), (n * (1.0 - e2) + h) * lat.sin()]
}

/// East, north, up of `p` relative to `origin` (both latitude, longitude in degrees, height in metres).
pub fn enu(origin: [f64; 3], p: [f64; 3]) -> [f64; 3] {
    let o = ecef(origin[0], origin[1], origin[2]);
    let q = ecef(p[0], p[1], p[2]);
    let d = [q[0] - o[0], q[1] - o[1], q[2] - o[2]];
    let (lat, lon) = (origin[0].to_radians(), origin[1].to_radians());
    let e = -lon.sin() * d[0] + lon.cos() * d[1];
    let n = -lat.sin() * lon.cos() * d[0] - lat.sin() * lon.sin() * d[1] + lat.cos() * d[2];
    let u = lat.cos() * lon.cos() * d[0] + lat.cos() * lon.sin() * d[1] + lat.sin() * d[2];
    [e, n, u]
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
