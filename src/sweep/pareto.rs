//! Pareto fronts: the measurements no other measurement beats on both counts (lower cost and higher score).
//! Used for held-out PSNR against training time (every cell at every evaluation point) and against peak memory,
//! over the cells that compete (those trained on every band of the sweep).

use super::result::CellResult;

/// Indices of the points not dominated in (cost: lower is better, score: higher is better), ordered by cost.
/// A point is dominated when another has cost <= and score >= with at least one strictly better; equal points are
/// all kept. Points with a non-finite cost or score are never on the front.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let ok = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let mut front: Vec<usize> = (0..points.len())
        .filter(|&i| ok(&points[i]))
        .filter(|&i| {
            let (c, s) = points[i];
            !points.iter().any(|q| ok(q) && q.0 <= c && q.1 >= s && (q.0 < c || q.1 > s))
        })
        .collect();
    front.sort_by(|&a, &b| {
        points[a].0.total_cmp(&points[b].0).then(points[b].1.total_cmp(&points[a].1)).then(a.cmp(&b))
    });
    front
}

/// The cells that compete on the fronts and in the report's picks: those trained on the most bands. A model of 3
/// bands is no substitute for one of 6, and its all-band PSNR averages other bands.
pub fn candidates(results: &[CellResult]) -> Vec<bool> {
    let most = results.iter().max_by_key(|r| r.band_names.len()).map(|r| r.band_names.clone()).unwrap_or_default();
    let set = |b: &[String]| {
        let mut v = b.to_vec();
        v.sort();
        v
    };
    let full = set(&most);
    results.iter().map(|r| set(&r.band_names) == full).collect()
}

/// Every measurement as (cell, point, training seconds, PSNR). The time is the point asked for (the same for every
/// cell), not the few milliseconds more that the crossing step took, so that the front compares like with like.
pub fn time_points(results: &[CellResult]) -> Vec<(usize, usize, f64, f64)> {
    results
        .iter()
        .enumerate()
        .flat_map(|(ci, r)| r.points.iter().enumerate().map(move |(pi, p)| (ci, pi, p.target_s, p.psnr)))
        .collect()
}

/// The PSNR-against-time front over the candidate cells: (cell, point), ordered by time.
pub fn time_front(results: &[CellResult]) -> Vec<(usize, usize)> {
    let ok = candidates(results);
    let pts: Vec<_> = time_points(results).into_iter().filter(|p| ok[p.0]).collect();
    let xy: Vec<(f64, f64)> = pts.iter().map(|p| (p.2, p.3)).collect();
    pareto_front(&xy).into_iter().map(|i| (pts[i].0, pts[i].1)).collect()
}

/// The cells with at least one point on the PSNR-against-time front, in order.
pub fn time_front_cells(results: &[CellResult]) -> Vec<usize> {
    let mut cells: Vec<usize> = time_front(results).into_iter().map(|p| p.0).collect();
    cells.sort_unstable();
    cells.dedup();
    cells
}

/// (peak GPU MiB, held-out PSNR at the end of the budget) per cell.
pub fn memory_points(results: &[CellResult]) -> Vec<(f64, f64)> {
    results
        .iter()
        .map(|r| (r.peak_gpu_bytes as f64 / 1048576.0, r.final_point().map_or(f64::NAN, |p| p.psnr)))
        .collect()
}

/// The PSNR-against-memory front over the candidate cells, ordered by memory.
pub fn memory_front(results: &[CellResult]) -> Vec<usize> {
    let ok = candidates(results);
    let pts: Vec<(f64, f64)> =
        memory_points(results).into_iter().zip(&ok).map(|(p, &c)| if c { p } else { (f64::NAN, f64::NAN) }).collect();
    pareto_front(&pts)
}
