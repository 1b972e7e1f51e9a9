//! Filling empty cells of a coarse height grid from their filled neighbours, the KNN inpainting that Pingel et al.
//! (2013) found as good as spring-metaphor inpainting for SMRF (and PDAL's SMRF once used): an empty cell takes the
//! mean of the [`NEIGHBOURS`] filled cells nearest to it, searched in a square that grows one ring at a time until
//! it holds that many, up to `max_radius` cells (beyond that the cell stays empty). Only originally filled cells are
//! sources, so the result does not depend on the order cells are visited.

/// Filled cells whose mean an empty cell takes.
pub const NEIGHBOURS: usize = 8;

/// Fills the NaN cells of the row-major `w` x `h` grid `v` (see the module doc); returns the number filled.
pub fn inpaint_knn(v: &mut [f64], w: usize, h: usize, max_radius: usize) -> usize {
    assert_eq!(v.len(), w * h, "one value per cell");
    let src: Vec<f64> = v.to_vec();
    let mut found: Vec<(i64, f64)> = Vec::new();
    let mut filled = 0;
    for r in 0..h {
        for c in 0..w {
            if src[r * w + c].is_finite() {
                continue;
            }
            found.clear();
            // Cells at Chebyshev distance <= radius, a ring at a time; once `radius` is in, every cell within
            // Euclidean distance `radius` has been seen, so NEIGHBOURS of those are the nearest NEIGHBOURS.
            let mut radius = 1usize;
            loop {
                ring(&src, w, h, r, c, radius, &mut found);
                let r2 = (radius * radius) as i64;
                if found.iter().filter(|(d2, _)| *d2 <= r2).count() >= NEIGHBOURS || radius >= max_radius {
                    break;
                }
                radius += 1;
            }
            if found.is_empty() {
                continue;
            }
            found.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
            let k = found.len().min(NEIGHBOURS);
            v[r * w + c] = found[..k].iter().map(|x| x.1).sum::<f64>() / k as f64;
            filled += 1;
        }
    }
    filled
}

/// Appends the filled cells on the square ring at Chebyshev distance `radius` around (r, c): (squared distance,
/// value).
fn ring(src: &[f64], w: usize, h: usize, r: usize, c: usize, radius: usize, out: &mut Vec<(i64, f64)>) {
    let rad = radius as i64;
    let (r, c) = (r as i64, c as i64);
    let mut visit = |rr: i64, cc: i64| {
        if rr >= 0 && cc >= 0 && (rr as usize) < h && (cc as usize) < w {
            let x = src[rr as usize * w + cc as usize];
            if x.is_finite() {
                out.push(((rr - r) * (rr - r) + (cc - c) * (cc - c), x));
            }
        }
    };
    for cc in c - rad..=c + rad {
        visit(r - rad, cc);
        visit(r + rad, cc);
    }
    for rr in r - rad + 1..r + rad {
        visit(rr, c - rad);
        visit(rr, c + rad);
    }
}
