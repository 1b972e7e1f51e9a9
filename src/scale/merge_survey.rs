//! Merged survey products of block-wise training (issue 23): `msnerf export dsm|ortho BLOCKS`. Every grid cell
//! belongs to one block, the one whose core holds the cell's centre on the partition's ground plane
//! ([`Owners::of_ground`]), so the overlaps are rendered by one block each and nothing is blended or doubled.
//!
//! 1. Each finished block renders the rectangle of cells it owns with its own run and the product's filters
//!    ([`render_survey`]), streamed into a scratch file beside the output (`(1 + B)` float32 per cell).
//! 2. The grid is then streamed row by row into the product writers ([`write_products`]): each cell from its
//!    owner's scratch file (read in order, one row per block at a time); cells of a missing block are nodata.
//!
//! Host memory is one block's row blocks while rendering and one grid row per block while merging; the scratch
//! files (the owned rectangles, about the grid's size) are removed when the merge ends, whether it succeeds or not.
//! Every block starts its vertical rays at the same height, the whole flight's median camera height.

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::error::ScaleError;
use super::merge::{finished_runs, Owners};
use super::partition::Blocks;
use crate::data::{load_dataset, LoadOptions};
use crate::gpu::Context;
use crate::nerf::run::LoadedRun;
use crate::nerf::survey::{
    render_survey, training_camera_height, RowBlock, SurveyError, SurveyGrid, SurveyOptions, SurveyStats,
};
use crate::nerf::survey_products::{write_products, RowSink, SurveyOutputs, SurveyReport, SurveySource};

/// Rows of the merged grid handed to the writers at a time.
const MERGE_ROWS: usize = 64;

/// One block's part of a merged survey.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BlockSurvey {
    pub block: String,
    /// Cells the block owns.
    pub owned: usize,
    /// Its owned cells with a DSM height (or, for an ortho alone, with band values).
    pub valid: usize,
    /// What its rendering of its rectangle did (its filters' counts cover the whole rectangle).
    pub stats: SurveyStats,
}

/// What a merged survey did.
#[derive(Debug, Clone)]
pub struct MergedSurvey {
    pub report: SurveyReport,
    pub blocks: Vec<BlockSurvey>,
    /// Blocks left out (`partial`); their cells are nodata.
    pub missing: Vec<String>,
}

/// Which block owns each cell of `grid`, row by row.
struct CellOwners<'a> {
    owners: Owners,
    grid: &'a SurveyGrid,
    ground_z: f64,
}

impl CellOwners<'_> {
    fn row(&self, r: usize, out: &mut Vec<usize>) {
        out.clear();
        out.extend((0..self.grid.width).map(|c| {
            let [x, y] = self.grid.centre(r, c);
            self.owners.of_ground(x, y, self.ground_z)
        }));
    }

    /// Per block: its cell count and the rectangle `[r0, r1) x [c0, c1)` that holds its cells.
    fn rectangles(&self, n: usize) -> Vec<(usize, [usize; 4])> {
        let mut rects = vec![(0usize, [usize::MAX, 0, usize::MAX, 0]); n];
        let mut row = Vec::new();
        for r in 0..self.grid.height {
            self.row(r, &mut row);
            for (c, &k) in row.iter().enumerate() {
                let (count, q) = &mut rects[k];
                *count += 1;
                *q = [q[0].min(r), q[1].max(r + 1), q[2].min(c), q[3].max(c + 1)];
            }
        }
        rects
    }
}

/// The world footprint of the blocks' cores on the ground plane, `[xmin, ymin, xmax, ymax]`: the default area.
pub fn cores_bounds(blocks: &Blocks) -> [f64; 4] {
    let levelled_to_world = glam::DMat3::from_cols_array_2d(&blocks.rotation); // columns = the rows of world->levelled
    let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for blk in &blocks.blocks {
        let [x0, x1, y0, y1] = blk.core;
        for (x, y) in [(x0, y0), (x0, y1), (x1, y0), (x1, y1)] {
            let p = levelled_to_world * glam::DVec3::new(x, y, blocks.ground_z);
            b = [b[0].min(p.x), b[1].min(p.y), b[2].max(p.x), b[3].max(p.y)];
        }
    }
    b
}

/// The flight's median training camera height (world z), from the partitioned dataset `ds` (load it with
/// `load_dataset(&blocks.source, ..)`).
pub fn flight_top(blocks: &Blocks, ds: &crate::data::Dataset) -> Result<f64, ScaleError> {
    let top = training_camera_height(ds);
    if top.is_finite() {
        Ok(top)
    } else {
        Err(ScaleError::Dataset { path: blocks.source.clone(), reason: "no training camera height".into() })
    }
}

/// Removes the scratch folder when the merge ends.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Renders and writes the merged products of the blocks in `dir` over `grid`. Blocks without a finished run are
/// refused by name, or left out with `partial`.
#[allow(clippy::too_many_arguments)]
pub fn merge_survey(
    ctx: &Context,
    dir: &Path,
    blocks: &Blocks,
    grid: &SurveyGrid,
    opts: &SurveyOptions,
    outputs: &SurveyOutputs,
    partial: bool,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<MergedSurvey, ScaleError> {
    let (runs, missing) = finished_runs(dir, blocks, partial)?;
    // finished_runs refuses a partition without any finished block.
    let Some(first) = runs.iter().flatten().next() else {
        return Err(ScaleError::option("BLOCKS", "no finished block"));
    };
    let product = outputs.dsm.as_ref().or(outputs.ortho.as_ref()).expect("a product is asked for");
    let out_dir = product.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
    let top = match opts.top {
        Some(t) => t,
        None => flight_top(blocks, &load_dataset(&blocks.source, &LoadOptions::default())?)?,
    };
    // The products' bands and CRS: the first finished block's run (every block's dataset is a part of one flight),
    // which renders first, so it is loaded once.
    let first_k = runs.iter().position(|r| r.as_ref() == Some(first)).unwrap_or(0);
    let loaded = LoadedRun::load(ctx, first)
        .map_err(|e| ScaleError::Block { block: blocks.blocks[first_k].name.clone(), reason: e.to_string() })?;
    let source = SurveySource {
        bands: loaded.ds.bands.clone(),
        crs: loaded.ds.crs.clone(),
        label: dir.display().to_string(),
        top,
        // The merged DSM has no view-count raster: each block saw its own cells.
        views: Vec::new(),
    };
    let mut first_run = Some(loaded);
    let nb = source.bands.len();
    let cells = CellOwners { owners: Owners::new(blocks), grid, ground_z: blocks.ground_z };
    let rects = cells.rectangles(blocks.blocks.len());
    let scratch = Scratch(out_dir.join(format!(".msnerf-merge-{}", std::process::id())));
    std::fs::create_dir_all(&scratch.0).map_err(ScaleError::io(&scratch.0))?;
    let mut parts: Vec<BlockSurvey> = Vec::new();
    let mut files: Vec<Option<(PathBuf, [usize; 4])>> = vec![None; blocks.blocks.len()];
    let report = write_products(&source, grid, opts, outputs, |opts, sink| {
        // 1. Every block renders the cells it owns into its scratch file.
        for (k, (b, run)) in blocks.blocks.iter().zip(&runs).enumerate() {
            let (owned, rect) = rects[k];
            let Some(run) = run else { continue };
            if owned == 0 {
                continue;
            }
            let sub = SurveyGrid {
                origin: [grid.origin[0] + rect[2] as f64 * grid.gsd, grid.origin[1] - rect[0] as f64 * grid.gsd],
                gsd: grid.gsd,
                width: rect[3] - rect[2],
                height: rect[1] - rect[0],
            };
            let path = scratch.0.join(format!("{}.f32", b.name));
            let io =
                |e: std::io::Error| SurveyError::Invalid { what: path.display().to_string(), reason: e.to_string() };
            let mut w = BufWriter::new(std::fs::File::create(&path).map_err(io)?);
            let mut loaded = match first_run.take().filter(|_| k == first_k) {
                Some(r) => r,
                None => LoadedRun::load(ctx, run)
                    .map_err(|e| SurveyError::Invalid { what: format!("block {}", b.name), reason: e.to_string() })?,
            };
            if loaded.ds.bands.len() != nb {
                return Err(SurveyError::Invalid {
                    what: format!("block {}", b.name),
                    reason: format!("{} bands, the other blocks {nb}", loaded.ds.bands.len()),
                });
            }
            let stats = render_survey(
                &mut loaded,
                &sub,
                opts,
                |blk: &RowBlock| {
                    let mut bytes = Vec::with_capacity(blk.height.len() * (2 + nb) * 4);
                    for (i, z) in blk.height.iter().enumerate() {
                        bytes.extend_from_slice(&z.to_le_bytes());
                        bytes.extend_from_slice(&f32::from(blk.quality[i]).to_le_bytes());
                        for v in &blk.values[i * nb..(i + 1) * nb] {
                            bytes.extend_from_slice(&v.to_le_bytes());
                        }
                    }
                    w.write_all(&bytes).map_err(io)
                },
                |rows| progress(&b.name, rows, sub.height),
            )?;
            w.flush().map_err(io)?;
            drop(loaded);
            parts.push(BlockSurvey { block: b.name.clone(), owned, valid: 0, stats });
            files[k] = Some((path, rect));
        }
        // 2. The grid, row by row, each cell from its owner.
        merge_rows(grid, nb, &cells, &files, outputs.dsm.is_some(), &mut parts, &blocks.blocks, sink)
    })
    .map_err(|e| ScaleError::Output { path: product.clone(), reason: e.to_string() })?;
    Ok(MergedSurvey { report, blocks: parts, missing })
}

/// A block's scratch file being read: the reader, the block's rectangle and its current row.
type BlockRows = (BufReader<std::fs::File>, [usize; 4], Vec<f32>);

/// Streams `grid` to `sink` from the blocks' scratch files; returns the merged statistics.
#[allow(clippy::too_many_arguments)]
fn merge_rows(
    grid: &SurveyGrid,
    nb: usize,
    cells: &CellOwners<'_>,
    files: &[Option<(PathBuf, [usize; 4])>],
    dsm: bool,
    parts: &mut [BlockSurvey],
    blocks: &[super::partition::Block],
    sink: &mut RowSink<'_>,
) -> Result<SurveyStats, SurveyError> {
    // Per cell: height, quality code, the bands.
    let per_cell = 2 + nb;
    let mut readers: Vec<Option<BlockRows>> = Vec::new();
    for f in files {
        readers.push(match f {
            Some((path, rect)) => {
                let file = std::fs::File::open(path)
                    .map_err(|e| SurveyError::Invalid { what: path.display().to_string(), reason: e.to_string() })?;
                Some((BufReader::new(file), *rect, vec![0.0f32; (rect[3] - rect[2]) * per_cell]))
            }
            None => None,
        });
    }
    let mut stats = SurveyStats { cells: grid.cells(), ..Default::default() };
    for p in parts.iter() {
        stats.rays += p.stats.rays;
        stats.seconds += p.stats.seconds;
        stats.top = p.stats.top;
    }
    let part_of: Vec<Option<usize>> = blocks.iter().map(|b| parts.iter().position(|p| p.block == b.name)).collect();
    let mut owner = Vec::new();
    let mut bytes = Vec::new();
    let mut row0 = 0;
    while row0 < grid.height {
        let rows = MERGE_ROWS.min(grid.height - row0);
        let mut block = RowBlock {
            row0,
            rows,
            height: vec![f32::NAN; rows * grid.width],
            values: vec![f32::NAN; rows * grid.width * nb],
            quality: vec![crate::nerf::survey::quality::NODATA; rows * grid.width],
        };
        for i in 0..rows {
            let r = row0 + i;
            for (k, rd) in readers.iter_mut().enumerate() {
                let Some((reader, rect, row)) = rd else { continue };
                if r < rect[0] || r >= rect[1] {
                    continue;
                }
                bytes.resize(row.len() * 4, 0);
                reader.read_exact(&mut bytes).map_err(|e| SurveyError::Invalid {
                    what: format!("block {} scratch file", blocks[k].name),
                    reason: e.to_string(),
                })?;
                for (v, b) in row.iter_mut().zip(bytes.chunks_exact(4)) {
                    *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
            cells.row(r, &mut owner);
            for (c, &k) in owner.iter().enumerate() {
                let Some((_, rect, row)) = &readers[k] else { continue };
                let src = &row[(c - rect[2]) * per_cell..(c - rect[2] + 1) * per_cell];
                let cell = i * grid.width + c;
                block.height[cell] = src[0];
                block.quality[cell] = src[1] as u8;
                block.values[cell * nb..(cell + 1) * nb].copy_from_slice(&src[2..]);
                let valid = if dsm { src[0].is_finite() } else { src[2..].iter().all(|v| v.is_finite()) };
                if valid {
                    stats.valid += 1;
                    if let Some(p) = part_of[k] {
                        parts[p].valid += 1;
                    }
                }
            }
        }
        sink(&block)?;
        row0 += rows;
    }
    Ok(stats)
}
