//! Tree tops: local maxima of a canopy height model in a circular window whose diameter grows with the height, the
//! variable-window filter of Popescu and Wynne (2004, "Seeing the trees in the forest", PE&RS 70(5):589-604). The
//! window's diameter at height h is their crown-width regression over deciduous and pine trees together,
//! 2.51503 + 0.00901 h^2 metres: a cell is a top when it is at least [`TopParams::min_height`] and no cell within
//! half that diameter is higher (of equal cells, the first in row-major order is the top, so a flat roof or a
//! plateau gives one top per window, not one per cell).
//!
//! The search runs on the CHM smoothed by a 3 x 3 median ([`median_3x3`]): a spike of a cell or two in a
//! photogrammetric surface is noise, not a tree top, and the median removes it while a crown's dome keeps its apex
//! within a few centimetres.

use crate::products::terrain::HeightGrid;

/// Parameters of [`find_tops`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TopParams {
    /// Lowest top, world units above the terrain (lidR's and most tools' 2 m).
    pub min_height: f64,
    /// Window diameter = a + b h + c h^2 (world units); default Popescu and Wynne's combined regression.
    pub window: [f64; 3],
    /// Fewest training images that saw a top (with the DSM's view counts): at the edge of a flight, where few
    /// images overlap, a photogrammetric surface has blobs that no tree made.
    pub min_views: usize,
}

impl Default for TopParams {
    fn default() -> Self {
        TopParams { min_height: 2.0, window: [2.51503, 0.0, 0.00901], min_views: 5 }
    }
}

impl TopParams {
    /// The search radius, world units, at height `h`.
    pub fn radius(&self, h: f64) -> f64 {
        0.5 * (self.window[0] + self.window[1] * h + self.window[2] * h * h)
    }
}

/// The cells (row-major indices) that are tree tops in `chm` (see the module doc), in row-major order.
pub fn find_tops(chm: &HeightGrid, p: &TopParams) -> Vec<usize> {
    let (w, h) = (chm.width, chm.height);
    let mut tops = Vec::new();
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            let z = chm.z[i];
            if !(z.is_finite() && z as f64 >= p.min_height) {
                continue;
            }
            let rad = (p.radius(z as f64) / chm.gsd).max(1.0);
            let n = rad.floor() as i64;
            let rad2 = rad * rad;
            let mut top = true;
            'window: for dr in -n..=n {
                let rr = r as i64 + dr;
                if rr < 0 || rr >= h as i64 {
                    continue;
                }
                for dc in -n..=n {
                    let cc = c as i64 + dc;
                    if cc < 0 || cc >= w as i64 || (dr * dr + dc * dc) as f64 > rad2 || (dr == 0 && dc == 0) {
                        continue;
                    }
                    let j = rr as usize * w + cc as usize;
                    let o = chm.z[j];
                    if o > z || (o == z && j < i) {
                        top = false;
                        break 'window;
                    }
                }
            }
            if top {
                tops.push(i);
            }
        }
    }
    tops
}

/// The 3 x 3 median of every cell with a height, over the neighbours that have one (NaN stays NaN).
pub fn median_3x3(g: &HeightGrid) -> HeightGrid {
    let (w, h) = (g.width, g.height);
    let mut out = g.clone();
    let mut v: Vec<f32> = Vec::with_capacity(9);
    for r in 0..h {
        for c in 0..w {
            if !g.z[r * w + c].is_finite() {
                continue;
            }
            v.clear();
            for rr in r.saturating_sub(1)..=(r + 1).min(h - 1) {
                for cc in c.saturating_sub(1)..=(c + 1).min(w - 1) {
                    let x = g.z[rr * w + cc];
                    if x.is_finite() {
                        v.push(x);
                    }
                }
            }
            v.sort_by(f32::total_cmp);
            let n = v.len();
            out.z[r * w + c] = if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) };
        }
    }
    out
}
