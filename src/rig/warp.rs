//! `Warp`: the map from the reference band's target pixels to a band's target pixels: a smooth residual shift
//! field (bilinear between nodes of a coarse grid), then the registration homography: `u = H (x + d(x))`.
//!
//! Why a field on top of the homography: at flight altitude the rig's parallax is nearly a translation, so the
//! bands differ by a homography only if every band's lens model is exact. When the per-band distortion
//! calibrations disagree, a band can sit a fraction of a pixel off in one part of the image while the best single
//! homography fits the rest. The field absorbs such smooth, low-order lens residuals and nothing finer: the
//! registration fits a polynomial to local shifts on a 128-px grid and keeps it only when the images support it
//! ([`super::register`]), then stores it sampled at the grid's nodes.

use super::register::Homography;

/// Shifts on a regular grid of nodes; node (i, j) sits at (i * step, j * step).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShiftField {
    pub nx: usize,
    pub ny: usize,
    pub step: f64,
    pub d: Vec<[f64; 2]>,
}

impl ShiftField {
    pub fn zeros(width: usize, height: usize, step: f64) -> ShiftField {
        let nx = ((width - 1) as f64 / step).ceil() as usize + 1;
        let ny = ((height - 1) as f64 / step).ceil() as usize + 1;
        ShiftField { nx, ny, step, d: vec![[0.0; 2]; nx * ny] }
    }

    /// Whether the grid is usable (nodes on both axes, a positive finite step, one finite shift per node): a
    /// field read back from a report is checked before [`ShiftField::at`] indexes it.
    pub fn is_consistent(&self) -> bool {
        self.nx >= 1
            && self.ny >= 1
            && self.step.is_finite()
            && self.step > 0.0
            && self.nx.checked_mul(self.ny) == Some(self.d.len())
            && self.d.iter().all(|v| v[0].is_finite() && v[1].is_finite())
    }

    /// Node position.
    pub fn node(&self, i: usize, j: usize) -> (f64, f64) {
        (i as f64 * self.step, j as f64 * self.step)
    }

    /// Bilinear shift at (x, y) (clamped to the grid).
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        let gx = (x / self.step).clamp(0.0, (self.nx - 1) as f64);
        let gy = (y / self.step).clamp(0.0, (self.ny - 1) as f64);
        let (i0, j0) = (
            (gx.floor() as usize).min(self.nx.saturating_sub(2)),
            (gy.floor() as usize).min(self.ny.saturating_sub(2)),
        );
        let (i1, j1) = ((i0 + 1).min(self.nx - 1), (j0 + 1).min(self.ny - 1));
        let (fx, fy) = (gx - i0 as f64, gy - j0 as f64);
        let g = |i: usize, j: usize| self.d[j * self.nx + i];
        let mut out = [0.0; 2];
        for (k, o) in out.iter_mut().enumerate() {
            let top = g(i0, j0)[k] * (1.0 - fx) + g(i1, j0)[k] * fx;
            let bot = g(i0, j1)[k] * (1.0 - fx) + g(i1, j1)[k] * fx;
            *o = top * (1.0 - fy) + bot * fy;
        }
        (out[0], out[1])
    }

    /// Largest shift over the nodes.
    pub fn max_norm(&self) -> f64 {
        self.d.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max)
    }
}

/// Homography plus optional residual field.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Warp {
    pub homography: Homography,
    pub field: Option<ShiftField>,
}

impl Warp {
    pub fn identity() -> Warp {
        Warp { homography: Homography::IDENTITY, field: None }
    }

    pub fn from_homography(h: Homography) -> Warp {
        Warp { homography: h, field: None }
    }

    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        match &self.field {
            None => self.homography.apply(x, y),
            Some(f) => {
                let (dx, dy) = f.at(x, y);
                self.homography.apply(x + dx, y + dy)
            }
        }
    }
}
