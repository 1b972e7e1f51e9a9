//! The Simple Morphological Filter (SMRF; Pingel, Clarke and McBride 2013, "An improved simple morphological filter
//! for the terrain classification of airborne LIDAR data", ISPRS J. 77:21-30), the ground filter of PDAL's
//! `filters.smrf` (which OpenDroneMap runs to make its DTM), applied to the cells of a DSM instead of LiDAR returns:
//!
//! 1. the minimum surface ZImin: each SMRF cell (`cell` world units, a whole number of DSM cells) takes the lowest
//!    DSM height inside it; empty cells are inpainted ([`super::inpaint`]);
//! 2. low outliers: the progressive filter on -ZImin with slope 5 and a 1-unit window, as PDAL runs it;
//! 3. objects: the progressive filter on ZImin: for radius k = 1 ..= ceil(window / cell), open the last surface with
//!    a disk of k cells ([`super::morphology`]); cells that the opening lowered by more than slope x cell x k are
//!    objects; the opened surface is the next step's;
//! 4. the provisional DEM ZIpro: ZImin without objects, low outliers and originally empty cells, inpainted;
//! 5. each DSM cell is ground when its height lies within threshold + scalar x slope(ZIpro) of ZIpro (both
//!    interpolated bilinearly at the cell's centre; the slope is the central-difference gradient's magnitude, rise
//!    over run);
//! 6. the final DTM: per SMRF cell the mean height of its ground cells, inpainted, interpolated bilinearly at every
//!    DSM cell ("reinterpolate a final DEM from the identified ground points", the paper's ZIfin).
//!
//! The DTM has a height wherever the DSM has one and the final surface reaches; cells the filter judged not ground
//! (buildings, crowns, cars) get the interpolated ground beneath them.

use super::grid::{bilinear, HeightGrid};
use super::inpaint::inpaint_knn;
use super::morphology::open;

/// SMRF's parameters, with PDAL `filters.smrf`'s defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmrfParams {
    /// SMRF cell size in world units (rounded to a whole number of DSM cells, at least one).
    pub cell: f64,
    /// Slope tolerance (rise over run) of the progressive opening.
    pub slope: f64,
    /// Largest window radius in world units: wider objects are not removed.
    pub window: f64,
    /// Elevation threshold of the final classification, world units.
    pub threshold: f64,
    /// Scale of the slope term of the final threshold.
    pub scalar: f64,
}

impl Default for SmrfParams {
    fn default() -> Self {
        SmrfParams { cell: 1.0, slope: 0.15, window: 18.0, threshold: 0.5, scalar: 1.25 }
    }
}

impl SmrfParams {
    /// Checks every parameter; the error names the first bad one (`cell`, `slope`, ...).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let all = [
            ("cell", self.cell),
            ("slope", self.slope),
            ("window", self.window),
            ("threshold", self.threshold),
            ("scalar", self.scalar),
        ];
        for (name, v) in all {
            let ok = v.is_finite() && if name == "scalar" || name == "threshold" { v >= 0.0 } else { v > 0.0 };
            if !ok {
                return Err((name, format!("must be a finite number > 0 (>= 0 for threshold and scalar), got {v}")));
            }
        }
        Ok(())
    }
}

/// The outcome of [`smrf`] on a DSM's grid.
#[derive(Debug, Clone)]
pub struct Smrf {
    /// Per DSM cell: judged ground (false where the DSM has no height).
    pub ground: Vec<bool>,
    /// The terrain height of every DSM cell (NaN where the DSM has none or the surface does not reach).
    pub dtm: HeightGrid,
    /// DSM cells per SMRF cell along each axis.
    pub factor: usize,
    /// The SMRF cells' object mask (coarse grid, row-major), for inspection.
    pub objects: Vec<bool>,
}

impl Smrf {
    pub fn ground_cells(&self) -> usize {
        self.ground.iter().filter(|&&g| g).count()
    }
}

/// Marks the cells the progressive opening of `z` (row-major `w` x `h`, no NaN) lowers by more than
/// `slope * cell * k` at radius k = 1 ..= ceil(`window` / `cell`).
pub fn progressive_filter(z: &[f64], w: usize, h: usize, cell: f64, slope: f64, window: f64) -> Vec<bool> {
    let mut obj = vec![false; w * h];
    let max_radius = (window / cell).ceil().max(1.0) as usize;
    let mut last = z.to_vec();
    for k in 1..=max_radius {
        let opened = open(&last, w, h, k);
        let dh = slope * cell * k as f64;
        for ((o, a), b) in obj.iter_mut().zip(&last).zip(&opened) {
            if a - b > dh {
                *o = true;
            }
        }
        last = opened;
    }
    obj
}

/// SMRF on `dsm`, using only the cells where `usable` is true (and the DSM has a height); see the module doc.
pub fn smrf(dsm: &HeightGrid, usable: &[bool], p: &SmrfParams) -> Smrf {
    let (w, h) = (dsm.width, dsm.height);
    assert_eq!(usable.len(), w * h, "one flag per cell");
    let k = ((p.cell / dsm.gsd).round() as usize).max(1);
    let cell = k as f64 * dsm.gsd;
    let (cw, ch) = (w.div_ceil(k), h.div_ceil(k));
    let obs = |i: usize| usable[i] && dsm.z[i].is_finite();
    // 1. The minimum surface.
    let mut zimin = vec![f64::NAN; cw * ch];
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            if obs(i) {
                let j = (r / k) * cw + c / k;
                let z = dsm.z[i] as f64;
                if zimin[j].is_nan() || z < zimin[j] {
                    zimin[j] = z;
                }
            }
        }
    }
    let empty: Vec<bool> = zimin.iter().map(|z| !z.is_finite()).collect();
    // Inpainting reaches as far as the widest object the filter removes; what lies beyond (outside the surveyed
    // area) is set to the highest surface, so it neither lowers the openings nor counts as ground.
    let reach = 2 * (p.window / cell).ceil().max(1.0) as usize;
    inpaint_knn(&mut zimin, cw, ch, reach);
    let top = zimin.iter().copied().filter(|z| z.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    if !top.is_finite() {
        return Smrf {
            ground: vec![false; w * h],
            dtm: HeightGrid::empty(w, h, dsm.gsd),
            factor: k,
            objects: vec![true; cw * ch],
        };
    }
    zimin.iter_mut().filter(|z| !z.is_finite()).for_each(|z| *z = top);
    // 2. Low outliers, 3. objects.
    let neg: Vec<f64> = zimin.iter().map(|z| -z).collect();
    let low = progressive_filter(&neg, cw, ch, cell, 5.0, 1.0);
    let objects = progressive_filter(&zimin, cw, ch, cell, p.slope, p.window);
    // 4. The provisional DEM.
    let mut zipro: Vec<f64> =
        (0..cw * ch).map(|j| if objects[j] || low[j] || empty[j] { f64::NAN } else { zimin[j] }).collect();
    inpaint_knn(&mut zipro, cw, ch, reach);
    let slope = gradient_magnitude(&zipro, cw, ch, cell);
    // 5. Ground cells of the DSM.
    let centre = |i: usize| -> (f64, f64) {
        let (r, c) = (i / w, i % w);
        ((c as f64 + 0.5) / k as f64 - 0.5, (r as f64 + 0.5) / k as f64 - 0.5)
    };
    let ground: Vec<bool> = (0..w * h)
        .map(|i| {
            if !obs(i) {
                return false;
            }
            let (u, t) = centre(i);
            let e = bilinear(&zipro, cw, ch, u, t);
            let s = bilinear(&slope, cw, ch, u, t);
            let s = if s.is_finite() { s } else { 0.0 };
            e.is_finite() && (dsm.z[i] as f64 - e).abs() <= p.threshold + p.scalar * s
        })
        .collect();
    // 6. The final surface from the ground cells.
    let (mut sum, mut n) = (vec![0.0f64; cw * ch], vec![0u32; cw * ch]);
    for (i, _) in ground.iter().enumerate().filter(|(_, &g)| g) {
        let j = (i / w / k) * cw + (i % w) / k;
        sum[j] += dsm.z[i] as f64;
        n[j] += 1;
    }
    let mut zifin: Vec<f64> = sum.iter().zip(&n).map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN }).collect();
    inpaint_knn(&mut zifin, cw, ch, reach);
    let mut dtm = HeightGrid::empty(w, h, dsm.gsd);
    for i in 0..w * h {
        if dsm.z[i].is_finite() {
            let (u, t) = centre(i);
            dtm.z[i] = bilinear(&zifin, cw, ch, u, t) as f32;
        }
    }
    Smrf { ground, dtm, factor: k, objects }
}

/// The magnitude of the central-difference gradient (one-sided at the edges and beside NaN), rise over run; NaN
/// where neither neighbour along an axis has a height.
pub fn gradient_magnitude(z: &[f64], w: usize, h: usize, cell: f64) -> Vec<f64> {
    let at = |r: usize, c: usize| z[r * w + c];
    let diff = |a: Option<f64>, m: f64, b: Option<f64>| -> f64 {
        let (a, b) = (a.filter(|x| x.is_finite()), b.filter(|x| x.is_finite()));
        match (a, b) {
            (Some(a), Some(b)) => (b - a) / (2.0 * cell),
            (Some(a), None) => (m - a) / cell,
            (None, Some(b)) => (b - m) / cell,
            (None, None) => 0.0,
        }
    };
    let mut out = vec![f64::NAN; w * h];
    for r in 0..h {
        for c in 0..w {
            let m = at(r, c);
            if !m.is_finite() {
                continue;
            }
            let gx = diff(c.checked_sub(1).map(|c| at(r, c)), m, (c + 1 < w).then(|| at(r, c + 1)));
            let gy = diff(r.checked_sub(1).map(|r| at(r, c)), m, (r + 1 < h).then(|| at(r + 1, c)));
            out[r * w + c] = (gx * gx + gy * gy).sqrt();
        }
    }
    out
}
