//! Thinning to a ground sampling distance: one point per cube of edge `cell` (world units), the best by the cloud's
//! confidence scalar fields (PDAL's `filters.voxeldownsize` keeps the first point of a voxel; a NeRF export knows
//! which point is most trustworthy, so it keeps that one). Cells are `floor(p / cell)` in the cloud's own
//! coordinates; ties go to the lowest index, so the result is deterministic.

use std::collections::HashMap;

use super::PointCloud;
use crate::output::{OutputError, Result};

/// Keeps the best point of every occupied cube: largest values of the `maximise` fields first (in order), then
/// smallest of the `minimise` fields. Fields the cloud does not carry are skipped. Returns the thinned cloud and the
/// kept indices (in their original order).
pub fn thin_to_grid(
    cloud: &PointCloud,
    cell: f64,
    maximise: &[&str],
    minimise: &[&str],
) -> Result<(PointCloud, Vec<usize>)> {
    cloud.validate()?;
    if !(cell.is_finite() && cell > 0.0) {
        return Err(OutputError::invalid("thinning cell", format!("{cell} is not a positive size")));
    }
    let field = |name: &&str| cloud.attributes.iter().find(|a| a.name == *name).map(|a| a.values.as_slice());
    let up: Vec<&[f32]> = maximise.iter().filter_map(field).collect();
    let down: Vec<&[f32]> = minimise.iter().filter_map(field).collect();
    // true when point a is better than point b
    let better = |a: usize, b: usize| {
        for f in &up {
            if f[a] != f[b] {
                return f[a] > f[b];
            }
        }
        for f in &down {
            if f[a] != f[b] {
                return f[a] < f[b];
            }
        }
        a < b
    };
    let mut best: HashMap<[i64; 3], usize> = HashMap::new();
    for (i, p) in cloud.positions.iter().enumerate() {
        let key = p.map(|v| (v / cell).floor() as i64);
        best.entry(key)
            .and_modify(|j| {
                if better(i, *j) {
                    *j = i;
                }
            })
            .or_insert(i);
    }
    let mut keep: Vec<usize> = best.into_values().collect();
    keep.sort_unstable();
    Ok((cloud.select(&keep), keep))
}
