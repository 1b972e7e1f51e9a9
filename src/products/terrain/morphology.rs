//! Grey-scale morphology with a disk-shaped structuring element of radius `r` cells (the cells (dr, dc) with
//! dr^2 + dc^2 <= r^2), as SMRF uses it. Cells outside the grid are left out of the minimum or maximum (the border is
//! not padded with a value).
//!
//! The disk is decomposed into rows: the erosion at (row, col) is the minimum over dr in -r..=r of the minimum of
//! row `row + dr` over columns `col - w(dr) ..= col + w(dr)`, with w(dr) = floor(sqrt(r^2 - dr^2)). Each row minimum
//! is a sliding-window minimum computed by van Herk / Gil-Werman (block prefix and suffix minima), so an erosion
//! costs O(cells x (2r + 1)) and holds two rows, whatever the radius.

/// Erosion (minimum over the disk of radius `r` cells) of the row-major `w` x `h` grid `v`.
pub fn erode(v: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    extremum(v, w, h, r, f64::min, f64::INFINITY)
}

/// Dilation (maximum over the disk).
pub fn dilate(v: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    extremum(v, w, h, r, f64::max, f64::NEG_INFINITY)
}

/// Opening: erosion, then dilation with the same disk.
pub fn open(v: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    dilate(&erode(v, w, h, r), w, h, r)
}

/// The disk's half-width on row offset `dr`.
pub fn half_width(r: usize, dr: usize) -> usize {
    let (r2, d2) = ((r * r) as i64, (dr * dr) as i64);
    let mut x = ((r2 - d2) as f64).sqrt() as i64;
    // Exact integer floor of the square root.
    while x * x > r2 - d2 {
        x -= 1;
    }
    while (x + 1) * (x + 1) <= r2 - d2 {
        x += 1;
    }
    x as usize
}

fn extremum(v: &[f64], w: usize, h: usize, r: usize, pick: fn(f64, f64) -> f64, neutral: f64) -> Vec<f64> {
    assert_eq!(v.len(), w * h, "one value per cell");
    let mut out = vec![neutral; w * h];
    let mut scratch = Scratch::default();
    let mut row_out = vec![neutral; w];
    for dr in 0..=r.min(h.saturating_sub(1)) {
        let hw = half_width(r, dr);
        for src in 0..h {
            sliding(&v[src * w..(src + 1) * w], hw, pick, neutral, &mut scratch, &mut row_out);
            // Source row `src` contributes to rows src - dr and src + dr.
            for dst in [src.checked_sub(dr), Some(src + dr).filter(|&d| d < h)].into_iter().flatten() {
                let o = &mut out[dst * w..(dst + 1) * w];
                for (a, &b) in o.iter_mut().zip(&row_out) {
                    *a = pick(*a, b);
                }
                if dr == 0 {
                    break;
                }
            }
        }
    }
    out
}

#[derive(Default)]
struct Scratch {
    padded: Vec<f64>,
    g: Vec<f64>,
    hh: Vec<f64>,
}

/// `out[c]` = pick over `row[c - hw ..= c + hw]` (clipped to the row), by van Herk / Gil-Werman.
fn sliding(row: &[f64], hw: usize, pick: fn(f64, f64) -> f64, neutral: f64, s: &mut Scratch, out: &mut [f64]) {
    let n = row.len();
    if hw == 0 {
        out.copy_from_slice(row);
        return;
    }
    let k = 2 * hw + 1;
    let len = n + 2 * hw;
    s.padded.clear();
    s.padded.resize(len, neutral);
    s.padded[hw..hw + n].copy_from_slice(row);
    s.g.resize(len, neutral);
    s.hh.resize(len, neutral);
    // g: running extremum from each block's start; hh: from each block's end.
    for i in 0..len {
        s.g[i] = if i % k == 0 { s.padded[i] } else { pick(s.g[i - 1], s.padded[i]) };
    }
    for i in (0..len).rev() {
        s.hh[i] = if i % k == k - 1 || i == len - 1 { s.padded[i] } else { pick(s.hh[i + 1], s.padded[i]) };
    }
    for (c, o) in out.iter_mut().enumerate() {
        // The window over padded[c ..= c + 2hw] covers row[c - hw ..= c + hw].
        *o = pick(s.hh[c], s.g[c + k - 1]);
    }
}
