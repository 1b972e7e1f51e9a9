//! Hillshade of a height grid (the DSM preview), as `gdaldem hillshade` draws it: Horn's 3 x 3 gradient, a sun at
//! azimuth 315 degrees (north-west, clockwise from north) and 45 degrees altitude, z factor 1.
//!
//! With p = dz/dx (east) and q = dz/dy (north) from Horn's weights, the surface normal is (-p, -q, 1) / |.| and the sun
//! direction (cos(alt) sin(az), cos(alt) cos(az), sin(alt)); their dot product c maps to grey 1 + 254 c (1 where the
//! slope faces away). 0 is nodata: edge cells and cells with a nodata neighbour, as gdaldem without
//! `-compute_edges`. `tests/output_hillshade.rs` compares with gdaldem itself.

/// Sun position of the hillshade.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    /// Degrees clockwise from north.
    pub azimuth: f64,
    /// Degrees above the horizon.
    pub altitude: f64,
}

impl Default for Sun {
    fn default() -> Self {
        Sun { azimuth: 315.0, altitude: 45.0 }
    }
}

/// Grey levels (row-major, 0 = nodata) of `heights` (`w` x `h`, north up, square cells of `gsd`); NaN is nodata.
pub fn hillshade(heights: &[f32], w: usize, h: usize, gsd: f64, sun: Sun) -> Vec<u8> {
    let mut out = vec![0u8; w * h];
    if w < 3 || h < 3 || heights.len() != w * h {
        return out;
    }
    let (az, alt) = (sun.azimuth.to_radians(), sun.altitude.to_radians());
    let s = [alt.cos() * az.sin(), alt.cos() * az.cos(), alt.sin()];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let z = |dx: isize, dy: isize| heights[(y as isize + dy) as usize * w + (x as isize + dx) as usize] as f64;
            let win = [z(-1, -1), z(0, -1), z(1, -1), z(-1, 0), z(0, 0), z(1, 0), z(-1, 1), z(0, 1), z(1, 1)];
            if win.iter().any(|v| !v.is_finite()) {
                continue;
            }
            let [a, b, c, d, _, f, g, hh, i] = win;
            let p = ((c + 2.0 * f + i) - (a + 2.0 * d + g)) / (8.0 * gsd);
            let q = ((a + 2.0 * b + c) - (g + 2.0 * hh + i)) / (8.0 * gsd);
            let cang = (s[2] - p * s[0] - q * s[1]) / (1.0 + p * p + q * q).sqrt();
            out[y * w + x] = if cang <= 0.0 { 1 } else { (1.0 + 254.0 * cang) as u8 };
        }
    }
    out
}
