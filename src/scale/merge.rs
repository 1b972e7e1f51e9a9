//! Merged outputs of block-wise training (issue 23): every world point belongs to exactly one block, the one whose
//! core contains it in the levelled frame of `blocks.json` (x and y only; the cores of the outer blocks reach to
//! infinity outward, so points beyond the footprint box still have one owner). Cores are half-open,
//! `[x0, x1) x [y0, y1)`, so a point on a shared edge is kept once. Each block's cloud is exported from its own run
//! and cut to its core, and the pieces are joined: no duplicated points in the overlaps.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::error::ScaleError;
use super::partition::{Block, Blocks};
use crate::output::pointcloud::{filter::crop, PointCloud};

/// What the merge did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct MergeStats {
    /// Per merged block: (name, points exported, points kept in its core).
    pub blocks: Vec<(String, usize, usize)>,
    /// Blocks left out (`partial`): not trained or not finished.
    pub missing: Vec<String>,
}

/// Which block owns a world point: the levelling and the cores' inner edges, found once for a whole cloud.
pub struct Owners {
    rotation: DMat3,
    /// Inner edges along x (between grid columns i-1 and i) and y, ascending.
    x_edges: Vec<f64>,
    y_edges: Vec<f64>,
    /// Block index of grid cell (ix, iy) at `iy * nx + ix`.
    cell_block: Vec<usize>,
    nx: usize,
}

impl Owners {
    pub fn new(blocks: &Blocks) -> Owners {
        let [nx, ny] = blocks.grid;
        let core = |ix: usize, iy: usize| blocks.blocks.iter().find(|b| b.index == [ix, iy]).map(|b| b.core);
        let mut cell_block = vec![0; nx * ny];
        for (k, b) in blocks.blocks.iter().enumerate() {
            cell_block[b.index[1] * nx + b.index[0]] = k;
        }
        Owners {
            rotation: DMat3::from_cols_array_2d(&blocks.rotation).transpose(),
            x_edges: (1..nx).map(|i| core(i, 0).map_or(f64::NAN, |c| c[0])).collect(),
            y_edges: (1..ny).map(|j| core(0, j).map_or(f64::NAN, |c| c[2])).collect(),
            cell_block,
            nx,
        }
    }

    /// The index (into `blocks.blocks`) of the block that owns world point `p`.
    pub fn of(&self, p: [f64; 3]) -> usize {
        let q = self.rotation * DVec3::from(p);
        let ix = self.x_edges.iter().take_while(|&&e| q.x >= e).count();
        let iy = self.y_edges.iter().take_while(|&&e| q.y >= e).count();
        self.cell_block[iy * self.nx + ix]
    }

    /// The owner of the point at world `x`, `y` on the partition's ground plane (levelled height `ground_z`): where
    /// a raster cell belongs. A levelled frame tilted by 90 degrees has no such point; `ground_z` is then the world z.
    pub fn of_ground(&self, x: f64, y: f64, ground_z: f64) -> usize {
        let r = self.rotation.row(2);
        let z = if r.z.abs() > 1e-6 { (ground_z - r.x * x - r.y * y) / r.z } else { ground_z };
        self.of([x, y, z])
    }
}

/// A block's run folder, when it finished training (a checkpoint and a summary).
pub fn finished_run(dir: &Path, b: &Block) -> Option<std::path::PathBuf> {
    let run = dir.join(&b.name).join("run");
    (run.join("checkpoints/latest.msnp").is_file() && run.join("summary.json").is_file()).then_some(run)
}

/// Every block's finished run (None where it has none) and the names of the blocks without one. Missing blocks are
/// refused by name unless `partial`; no finished block at all is refused always.
pub fn finished_runs(
    dir: &Path,
    blocks: &Blocks,
    partial: bool,
) -> Result<(Vec<Option<std::path::PathBuf>>, Vec<String>), ScaleError> {
    let runs: Vec<Option<std::path::PathBuf>> = blocks.blocks.iter().map(|b| finished_run(dir, b)).collect();
    let missing: Vec<String> =
        blocks.blocks.iter().zip(&runs).filter(|(_, r)| r.is_none()).map(|(b, _)| b.name.clone()).collect();
    if !missing.is_empty() && !partial {
        return Err(ScaleError::Block {
            block: missing.join(", "),
            reason: "not trained or not finished (run `msnerf train-blocks`, or use the others with --partial)".into(),
        });
    }
    if runs.iter().all(Option::is_none) {
        return Err(ScaleError::Block { block: "all".into(), reason: "no block has a finished run".into() });
    }
    Ok((runs, missing))
}

/// Exports every block's cloud with `export` (given the block and its run folder) and joins the core parts. Blocks
/// without a finished run are refused by name, or left out with `partial` (listed in the stats).
pub fn merge_clouds(
    dir: &Path,
    blocks: &Blocks,
    partial: bool,
    mut export: impl FnMut(&Block, &Path) -> Result<PointCloud, ScaleError>,
) -> Result<(PointCloud, MergeStats), ScaleError> {
    let (runs, missing) = finished_runs(dir, blocks, partial)?;
    let mut stats = MergeStats { missing, ..Default::default() };
    let owners = Owners::new(blocks);
    let mut merged: Option<PointCloud> = None;
    for (i, (b, run)) in blocks.blocks.iter().zip(&runs).enumerate() {
        let Some(run) = run else { continue };
        let cloud = export(b, run)?;
        let exported = cloud.len();
        let (kept, _) = crop(&cloud, |p| owners.of(*p) == i)
            .map_err(|e| ScaleError::Block { block: b.name.clone(), reason: e.to_string() })?;
        stats.blocks.push((b.name.clone(), exported, kept.len()));
        merged = Some(match merged {
            None => kept,
            Some(m) => append(m, kept).map_err(|reason| ScaleError::Block { block: b.name.clone(), reason })?,
        });
    }
    let merged = merged
        .ok_or_else(|| ScaleError::Block { block: "all".into(), reason: "no block has a finished run".into() })?;
    Ok((merged, stats))
}

/// `a` followed by `b` (same bands; normals, colours and scalar fields kept where both have them).
fn append(mut a: PointCloud, b: PointCloud) -> Result<PointCloud, String> {
    if a.bands != b.bands {
        return Err("its bands differ from the other blocks'".into());
    }
    a.positions.extend(b.positions);
    a.values.extend(b.values);
    a.normals = match (a.normals.take(), b.normals) {
        (Some(mut x), Some(y)) => {
            x.extend(y);
            Some(x)
        }
        _ => None,
    };
    a.rgb = match (a.rgb.take(), b.rgb) {
        (Some(mut x), Some(y)) => {
            x.extend(y);
            Some(x)
        }
        _ => None,
    };
    let mut attrs = Vec::new();
    for mut f in std::mem::take(&mut a.attributes) {
        if let Some(g) = b.attributes.iter().find(|g| g.name == f.name) {
            f.values.extend(&g.values);
            attrs.push(f);
        }
    }
    a.attributes = attrs;
    Ok(a)
}
