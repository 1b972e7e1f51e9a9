//! `msnerf partition DATASET --blocks AxB --overlap F --out BLOCKS` (issue 23): a grid of blocks over the ground
//! the cameras see, each block a dataset of its own that trains independently (Mega-NeRF's spatial blocks; ODM's
//! split-merge).
//!
//! - **The ground area** is the aerial normalisation's footprint ([`crate::data::aerial::ground_footprint_with`]):
//!   in the levelled world frame (the world itself when the dataset has a `crs`, whose z is up; else the cameras'
//!   mean up turned to +z), the 2nd-98th percentile box of where the images' corner and centre rays meet the ground
//!   height z_g: `--ground-z`, or where pairs of optical axes meet. A layout with no such ground (cameras that do
//!   not look down; a nadir grid's parallel axes without `--ground-z`) is refused with the reason.
//! - **Blocks**: A x B equal cells of that box (x then y), the *core*; each grown on every side by `overlap` times
//!   its own size, the *grown* bounds.
//! - **Which frames a block gets** (Mega-NeRF assigns a ray to every cell it passes through): a frame belongs to a
//!   block when any of a 9 x 9 grid of its pixel rays (edges and centre included) passes through the block's grown
//!   box from `z_g - 0.05 H` to `z_g + 0.5 H` (H the cameras' mean height above the ground: what stands on the
//!   ground up to half the flight height). Train and eval frames are assigned alike and keep their split
//!   (written per frame).
//! - **Each block dataset** is `BLOCKS/<block>/transforms.json`: the source's keys and its frames' entries as
//!   written, image, mask and depth paths made absolute (no image is copied). `BLOCKS/blocks.json` lists the blocks
//!   with their core and grown bounds and frame counts. Written into a staging folder, renamed when complete.

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::error::ScaleError;
use crate::data::aerial::ground_footprint_with;
use crate::data::camera::camera_direction;
use crate::data::{load_dataset, Dataset, LoadOptions, Split};
use crate::util::staging::StagingDir;

/// Blocks covered by fewer training views than this are warned about.
pub const MIN_BLOCK_VIEWS: usize = 12;
/// Pixel rays per image side tested against a block.
const RAY_GRID: usize = 9;

/// One block of `blocks.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Block {
    /// Folder name under BLOCKS (`block_<ix>_<iy>`).
    pub name: String,
    pub index: [usize; 2],
    /// x0, x1, y0, y1 in the levelled world frame: the points this block owns when outputs are merged.
    pub core: [f64; 4],
    /// The core grown by the overlap: the area the block's frames are chosen for.
    pub grown: [f64; 4],
    pub train_frames: usize,
    pub eval_frames: usize,
}

/// `blocks.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Blocks {
    /// The source dataset's transforms.json (absolute).
    pub source: PathBuf,
    pub grid: [usize; 2],
    pub overlap: f64,
    /// World -> levelled frame (rows).
    pub rotation: [[f64; 3]; 3],
    pub ground_z: f64,
    /// Height of the block boxes' top above the ground.
    pub box_height: f64,
    pub blocks: Vec<Block>,
    /// Blocks with fewer than [`MIN_BLOCK_VIEWS`] training views.
    pub warnings: Vec<String>,
}

/// Options of [`partition`].
#[derive(Debug, Clone)]
pub struct PartitionOptions {
    pub blocks: [usize; 2],
    pub overlap: f64,
    /// The ground height (levelled frame: world z for a dataset with a `crs`); default: where the cameras' optical
    /// axes meet, which a nadir grid flight (parallel axes) cannot give.
    pub ground_z: Option<f64>,
    pub overwrite: bool,
}

/// Parses `AxB` (e.g. `2x2`).
pub fn parse_grid(s: &str) -> Result<[usize; 2], ScaleError> {
    let bad = || ScaleError::option("--blocks", format!("`{s}`: expected AxB with A, B >= 1 (e.g. 2x2)"));
    let (a, b) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (a, b) = (a.trim().parse::<usize>().map_err(|_| bad())?, b.trim().parse::<usize>().map_err(|_| bad())?);
    if a == 0 || b == 0 {
        return Err(bad());
    }
    Ok([a, b])
}

/// Whether the ray `o + t d` (t > 0) passes through the box `lo..hi` (slab test).
pub fn ray_meets_box(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
}

/// The levelled rays of a frame's 9 x 9 pixel grid: (centre, directions).
fn frame_rays(ds: &Dataset, f: usize, r: &glam::DMat3) -> (DVec3, Vec<DVec3>) {
    let frame = &ds.frames[f];
    let p = &frame.c2w;
    let col = |c: usize| DVec3::new(p[0][c], p[1][c], p[2][c]);
    let k = frame.camera.intrinsics::<f64>();
    let (w, h) = (frame.camera.width as f64, frame.camera.height as f64);
    let mut dirs = Vec::with_capacity(RAY_GRID * RAY_GRID);
    for i in 0..RAY_GRID {
        for j in 0..RAY_GRID {
            let (v, u) = (h * i as f64 / (RAY_GRID - 1) as f64, w * j as f64 / (RAY_GRID - 1) as f64);
            let dc = DVec3::from(camera_direction(&k, v, u));
            dirs.push(*r * (col(0) * dc.x + col(1) * dc.y + col(2) * dc.z));
        }
    }
    (*r * col(3), dirs)
}

/// Makes the blocks of `input` (a dataset folder or its transforms.json) in `out`.
pub fn partition(input: &Path, out: &Path, o: &PartitionOptions) -> Result<Blocks, ScaleError> {
    partition_with(input, out, o, None).map(|(b, _)| b)
}

/// [`partition`], and with `slurm` the job array `out/slurm.sh` written into the staging folder before it is
/// renamed, so a failure leaves no blocks folder behind; returns the memory per task the script asks for, GiB.
pub fn partition_with(
    input: &Path,
    out: &Path,
    o: &PartitionOptions,
    slurm: Option<&super::slurm::SlurmOptions>,
) -> Result<(Blocks, Option<u64>), ScaleError> {
    check_overlap(o)?;
    partition_dataset(&load_dataset(input, &LoadOptions::default())?, out, o, slurm)
}

/// `--overlap` within [0, 1), checked before anything is read or written.
fn check_overlap(o: &PartitionOptions) -> Result<(), ScaleError> {
    if !(0.0..1.0).contains(&o.overlap) {
        return Err(ScaleError::option("--overlap", format!("{} is outside [0, 1)", o.overlap)));
    }
    Ok(())
}

/// [`partition_with`] on a dataset already loaded (the CLI loads it once, also for the Slurm time estimate).
pub fn partition_dataset(
    ds: &Dataset,
    out: &Path,
    o: &PartitionOptions,
    slurm: Option<&super::slurm::SlurmOptions>,
) -> Result<(Blocks, Option<u64>), ScaleError> {
    check_overlap(o)?;
    let [nx, ny] = o.blocks;
    let usable: Vec<usize> = (0..ds.frames.len()).filter(|&f| ds.frames[f].split != Split::Unused).collect();
    if nx * ny > usable.len() {
        return Err(ScaleError::option(
            "--blocks",
            format!("{nx}x{ny} = {} blocks for {} frames: more blocks than frames", nx * ny, usable.len()),
        ));
    }
    let cams: Vec<_> = ds.frames.iter().map(|f| (f.c2w, f.camera)).collect();
    // A projected CRS has z up: no levelling. Otherwise the cameras' mean up is turned to +z.
    let levelling = ds.crs.as_ref().map(|_| glam::DMat3::IDENTITY);
    let g = ground_footprint_with(&cams, levelling, o.ground_z).map_err(|e| ScaleError::Dataset {
        path: ds.transforms_path.clone(),
        reason: format!("no ground area to partition: {e} (give the ground height with --ground-z)"),
    })?;
    let [x0, x1, y0, y1] = g.bounds;
    if !(x1 > x0 && y1 > y0 && g.height.is_finite() && g.height > 0.0) {
        return Err(ScaleError::Dataset {
            path: ds.transforms_path.clone(),
            reason: format!("degenerate ground area: x {x0}..{x1}, y {y0}..{y1}, camera height {}", g.height),
        });
    }
    let box_height = 0.5 * g.height;
    let (z_lo, z_hi) = (g.ground_z - 0.05 * g.height, g.ground_z + box_height);
    let rays: Vec<(DVec3, Vec<DVec3>)> = usable.iter().map(|&f| frame_rays(ds, f, &g.rotation)).collect();
    let (sx, sy) = ((x1 - x0) / nx as f64, (y1 - y0) / ny as f64);
    let mut blocks = Vec::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    let mut warnings = Vec::new();
    for iy in 0..ny {
        for ix in 0..nx {
            let core = [x0 + sx * ix as f64, x0 + sx * (ix + 1) as f64, y0 + sy * iy as f64, y0 + sy * (iy + 1) as f64];
            let grown = [
                core[0] - o.overlap * sx,
                core[1] + o.overlap * sx,
                core[2] - o.overlap * sy,
                core[3] + o.overlap * sy,
            ];
            let (lo, hi) = (DVec3::new(grown[0], grown[2], z_lo), DVec3::new(grown[1], grown[3], z_hi));
            let frames: Vec<usize> = usable
                .iter()
                .zip(&rays)
                .filter(|(_, (c, dirs))| dirs.iter().any(|d| ray_meets_box(*c, *d, lo, hi)))
                .map(|(&f, _)| f)
                .collect();
            let count = |s: Split| frames.iter().filter(|&&f| ds.frames[f].split == s).count();
            let name = format!("block_{ix}_{iy}");
            let (train, eval) = (count(Split::Train), count(Split::Eval));
            if train == 0 {
                return Err(ScaleError::Dataset {
                    path: ds.transforms_path.clone(),
                    reason: format!(
                        "{name} (x {:.3}..{:.3}, y {:.3}..{:.3}) has no training frame: use fewer blocks or more overlap",
                        grown[0], grown[1], grown[2], grown[3]
                    ),
                });
            }
            if train < MIN_BLOCK_VIEWS {
                let w = format!(
                    "{name}: only {train} training views (fewer than {MIN_BLOCK_VIEWS}): its geometry will be weak"
                );
                log::warn!("{w}");
                warnings.push(w);
            }
            blocks.push(Block { name, index: [ix, iy], core, grown, train_frames: train, eval_frames: eval });
            members.push(frames);
        }
    }
    let stage = StagingDir::new(out, o.overwrite)
        .map_err(|e| ScaleError::Output { path: out.to_path_buf(), reason: e.to_string() })?;
    let source: Value = crate::data::transforms::read_json(&ds.transforms_path, "transforms.json")?;
    let src_dir = std::path::absolute(ds.transforms_path.parent().unwrap_or(Path::new(".")))
        .map_err(|e| ScaleError::Output { path: ds.transforms_path.clone(), reason: e.to_string() })?;
    // The source's sparse points (SfM tracks), read once; each block gets the part its frames observed.
    let points: Option<(std::path::PathBuf, Value)> = match source.get("sparse_points_path").and_then(Value::as_str) {
        Some(p) => {
            let path = src_dir.join(p);
            // Checked as training would check it (frames known, finite points), so a bad file fails here by name.
            crate::data::sparse_points::read_sparse_points(ds, &path)?;
            let doc: Value = crate::data::transforms::read_json(&path, "sparse_points_path")?;
            Some((path, doc))
        }
        None => None,
    };
    for (b, frames) in blocks.iter().zip(&members) {
        let mut doc = block_transforms(&source, ds, frames, &src_dir);
        let dir = stage.path.join(&b.name);
        std::fs::create_dir_all(&dir).map_err(ScaleError::io(&dir))?;
        if let Some((path, pts)) = &points {
            let part = block_sparse_points(pts, ds, frames, &src_dir)
                .map_err(|reason| ScaleError::Dataset { path: path.clone(), reason })?;
            let p = dir.join("sparse_points.json");
            std::fs::write(&p, serde_json::to_vec(&part).expect("json")).map_err(ScaleError::io(&p))?;
            doc["sparse_points_path"] = Value::String("sparse_points.json".into());
        }
        let p = dir.join("transforms.json");
        std::fs::write(&p, serde_json::to_vec_pretty(&doc).expect("json")).map_err(ScaleError::io(&p))?;
    }
    let rot = g.rotation;
    let result = Blocks {
        source: src_dir.join(ds.transforms_path.file_name().unwrap_or("transforms.json".as_ref())),
        grid: o.blocks,
        overlap: o.overlap,
        rotation: [0, 1, 2].map(|i| [0, 1, 2].map(|j| rot.col(j)[i])),
        ground_z: g.ground_z,
        box_height,
        blocks,
        warnings,
    };
    let p = stage.path.join(super::BLOCKS_FILE);
    std::fs::write(&p, serde_json::to_vec_pretty(&result).expect("json")).map_err(ScaleError::io(&p))?;
    let gib = match slurm {
        Some(so) => Some(super::slurm::write_job_array_into(&stage.path, out, &result, so)?),
        None => None,
    };
    stage.commit().map_err(|e| ScaleError::Output { path: out.to_path_buf(), reason: e.to_string() })?;
    Ok((result, gib))
}

/// A block's transforms.json: the source's top-level keys (split lists left out: each frame says its split), its
/// frames' entries as written with paths made absolute.
fn block_transforms(source: &Value, ds: &Dataset, frames: &[usize], src_dir: &Path) -> Value {
    let abs = |v: &Value| -> Value {
        match v.as_str() {
            Some(p) if !Path::new(p).is_absolute() => Value::String(src_dir.join(p).display().to_string()),
            _ => v.clone(),
        }
    };
    let mut doc = source.clone();
    let top = doc.as_object_mut().expect("the loader read an object");
    for k in ["train_filenames", "val_filenames", "test_filenames"] {
        top.remove(k);
    }
    if let Some(p) = top.get("sparse_points_path").map(&abs) {
        top.insert("sparse_points_path".into(), p);
    }
    let all = source.get("frames").and_then(Value::as_array).cloned().unwrap_or_default();
    let out: Vec<Value> = frames
        .iter()
        .map(|&f| {
            let frame = &ds.frames[f];
            let mut v = all[frame.index_in_file].clone();
            let o = v.as_object_mut().expect("the loader read the frame");
            for k in ["file_path", "mask_path", "depth_file_path"] {
                if let Some(p) = o.get(k).map(&abs) {
                    o.insert(k.into(), p);
                }
            }
            if let Some(list) = o.get("band_files").and_then(Value::as_array).map(|l| l.iter().map(&abs).collect()) {
                o.insert("band_files".into(), Value::Array(list));
            }
            let split = match frame.split {
                Split::Train => "train",
                Split::Eval => "eval",
                Split::Test => "test",
                Split::Unused => "train",
            };
            o.insert("split".into(), split.into());
            v
        })
        .collect();
    top.insert("frames".into(), Value::Array(out));
    doc
}

/// A block's sparse points: the source's points with their tracks cut to the block's frames (named as the block's
/// transforms.json names them: absolute paths); a point keeps its other keys and is dropped when no training frame
/// of the block observed it (depth supervision projects a point into the training frames of its track).
fn block_sparse_points(points: &Value, ds: &Dataset, frames: &[usize], src_dir: &Path) -> Result<Value, String> {
    let abs = |p: &str| -> String {
        if Path::new(p).is_absolute() {
            p.to_string()
        } else {
            src_dir.join(p).display().to_string()
        }
    };
    let members: std::collections::HashMap<&str, bool> = frames
        .iter()
        .map(|&f| (ds.frames[f].name.as_str(), matches!(ds.frames[f].split, Split::Train | Split::Unused)))
        .collect();
    let list = points.get("points").and_then(Value::as_array).ok_or("no `points` list")?;
    let mut kept = Vec::new();
    for (i, p) in list.iter().enumerate() {
        let track = p.get("frames").and_then(Value::as_array).ok_or_else(|| format!("points[{i}].frames missing"))?;
        let mut names = Vec::new();
        let mut trained = false;
        for name in track.iter().filter_map(Value::as_str) {
            if let Some(&train) = members.get(name) {
                names.push(Value::String(abs(name)));
                trained |= train;
            }
        }
        if trained {
            let mut q = p.clone();
            q["frames"] = Value::Array(names);
            kept.push(q);
        }
    }
    Ok(serde_json::json!({ "points": kept }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_parse_and_rays_meet_boxes() {
        assert_eq!(parse_grid("2x3").unwrap(), [2, 3]);
        for bad in ["2", "0x2", "ax2", "2x"] {
            assert!(parse_grid(bad).unwrap_err().to_string().contains("--blocks"), "{bad}");
        }
        let (lo, hi) = (DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 1.0, 1.0));
        assert!(ray_meets_box(DVec3::new(0.5, 0.5, 5.0), DVec3::new(0.0, 0.0, -1.0), lo, hi));
        assert!(!ray_meets_box(DVec3::new(0.5, 0.5, 5.0), DVec3::new(0.0, 0.0, 1.0), lo, hi), "behind the camera");
        assert!(!ray_meets_box(DVec3::new(2.5, 0.5, 5.0), DVec3::new(0.0, 0.0, -1.0), lo, hi));
        assert!(ray_meets_box(DVec3::new(-4.0, 0.5, 5.0), DVec3::new(1.0, 0.0, -1.0), lo, hi), "oblique");
    }
}
