//! [`HeightGrid`]: a north-up raster of heights in world units, row-major, NaN where there is no height.

/// A north-up height raster: `z[row * width + col]`, NaN = nodata; cells of `gsd` world units.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightGrid {
    pub width: usize,
    pub height: usize,
    pub gsd: f64,
    pub z: Vec<f32>,
}

impl HeightGrid {
    /// A grid of `width` x `height` cells of `gsd`, all nodata.
    pub fn empty(width: usize, height: usize, gsd: f64) -> HeightGrid {
        HeightGrid { width, height, gsd, z: vec![f32::NAN; width * height] }
    }

    pub fn cells(&self) -> usize {
        self.width * self.height
    }

    pub fn at(&self, row: usize, col: usize) -> f32 {
        self.z[row * self.width + col]
    }

    /// The number of cells with a height.
    pub fn valid(&self) -> usize {
        self.z.iter().filter(|v| v.is_finite()).count()
    }
}

/// Bilinear interpolation of the row-major `w` x `h` grid `v` at fractional (column, row) `(u, t)` in cell-centre
/// coordinates (cell (0, 0)'s centre is (0, 0)), clamped to the grid; the corners that are NaN are left out and the
/// others' weights renormalised (NaN when all four are).
pub fn bilinear(v: &[f64], w: usize, h: usize, u: f64, t: f64) -> f64 {
    let u = u.clamp(0.0, (w - 1) as f64);
    let t = t.clamp(0.0, (h - 1) as f64);
    let (c0, r0) = (u.floor() as usize, t.floor() as usize);
    let (c1, r1) = ((c0 + 1).min(w - 1), (r0 + 1).min(h - 1));
    let (fu, ft) = (u - c0 as f64, t - r0 as f64);
    let corners =
        [(r0, c0, (1.0 - fu) * (1.0 - ft)), (r0, c1, fu * (1.0 - ft)), (r1, c0, (1.0 - fu) * ft), (r1, c1, fu * ft)];
    let (mut sw, mut s) = (0.0, 0.0);
    for (r, c, wt) in corners {
        let x = v[r * w + c];
        if x.is_finite() && wt > 0.0 {
            sw += wt;
            s += wt * x;
        }
    }
    if sw > 0.0 {
        s / sw
    } else {
        // All weight on NaN corners (or exactly on a NaN cell): the nearest finite corner, if any.
        corners.iter().map(|&(r, c, _)| v[r * w + c]).find(|x| x.is_finite()).unwrap_or(f64::NAN)
    }
}
