//! Depth targets of depth supervision (`loss.depth`, docs/geometry.md "Depth supervision"): per training frame, the
//! distance along the ray through a pixel's centre to the surface, in world units, from the frames' depth maps
//! (`depth_file_path`, 0 = no depth, nerfstudio's convention) or from the dataset's sparse points projected into the
//! training frames of their tracks. Built once before training; each batch gets (distance, sigma) per ray in the
//! normalised frame, (0, 1) where a pixel has no target, and optionally a share of rays drawn from target pixels.

use super::config::{DepthSource, DepthSupervision};
use super::error::{NerfError, NerfResult};
use crate::data::camera::project_point;
use crate::data::sparse_points::read_sparse_points;
use crate::data::{CameraModel, Dataset, ImageCache, PixelBatch};
use rand::Rng;
use std::collections::HashMap;

/// One frame's targets: world distances at sorted pixel indices (row * width + col); depth maps keep only their
/// valid pixels, so lookups and draws work the same for dense and sparse sources.
struct FrameDepth {
    pixels: Vec<u32>,
    dist: Vec<f32>,
}

impl FrameDepth {
    fn from_pairs(mut v: Vec<(u32, f32)>) -> Self {
        v.retain(|&(_, d)| d > 0.0 && d.is_finite());
        v.sort_by_key(|&(q, _)| q);
        let (pixels, dist) = v.into_iter().unzip();
        FrameDepth { pixels, dist }
    }

    fn get(&self, q: u32) -> Option<f32> {
        self.pixels.binary_search(&q).ok().map(|i| self.dist[i])
    }
}

/// Largest plausible median |x|_inf of a frame's target points in the normalised frame (the scene is [-1, 1]^3).
const MAX_REACH: f64 = 4.0;

/// Depth targets of the training frames.
pub struct DepthTargets {
    frames: HashMap<usize, FrameDepth>,
    /// Targets per frame (for drawing target pixels).
    counts: HashMap<usize, usize>,
    width: u32,
    /// World to normalised units.
    scale: f64,
    /// Standard deviation, world units.
    sigma: f64,
    ray_fraction: f64,
}

impl DepthTargets {
    /// Targets for `frames` (dataset indices, the train split) as `cfg` asks. Errors name the config key, file and
    /// frame: no depth in the dataset, a point that does not project into a frame of its track, a depth map of the
    /// wrong size or band count, or distances outside the sampling range (a unit mistake).
    pub fn build(ds: &Dataset, frames: &[usize], cfg: &DepthSupervision, near_far: (f64, f64)) -> NerfResult<Self> {
        let scale = ds.pose_transform().scale;
        let mut out = DepthTargets {
            frames: HashMap::new(),
            counts: HashMap::new(),
            width: ds.width,
            scale,
            sigma: cfg.sigma,
            ray_fraction: cfg.ray_fraction,
        };
        match cfg.source {
            DepthSource::DepthMaps => out.dense(ds, frames)?,
            DepthSource::SparsePoints => out.sparse(ds, frames)?,
        }
        // A depth map without one valid pixel (all 0 = no depth, NaN or negative) adds nothing: that frame is left
        // out of depth supervision by name, the others keep theirs.
        let mut empty: Vec<usize> = out.frames.iter().filter(|(_, d)| d.pixels.is_empty()).map(|(&f, _)| f).collect();
        empty.sort_unstable();
        for f in empty {
            out.frames.remove(&f);
            let frame = &ds.frames[f];
            let file = frame.depth.as_ref().map_or(String::new(), |p| format!(" ({})", p.display()));
            log::warn!(
                "frame `{}`: its depth map{file} has no valid pixel (every value 0, negative or not finite): the \
                 frame trains without depth supervision",
                frame.name
            );
        }
        out.counts = out.frames.iter().map(|(&f, d)| (f, d.pixels.len())).collect();
        if out.total() == 0 {
            return Err(NerfError::invalid(
                "loss.depth.source",
                format!("{}: no training pixel has a depth target", ds.transforms_path.display()),
            ));
        }
        // A unit mistake (millimetres read as metres, a wrong depth_unit_scale_factor) puts the surface far outside the
        // normalised scene ([-1, 1]^3 holds the cameras and what they look at): refused by name rather than trained
        // into garbage. Checked on up to 256 targets per frame, per frame's median.
        let t = ds.pose_transform();
        let (near, far) = near_far;
        for (&f, d) in &out.frames {
            let frame = &ds.frames[f];
            let step = (d.pixels.len() / 256).max(1);
            let mut reach: Vec<f64> = Vec::new();
            let mut dist: Vec<f64> = Vec::new();
            for k in (0..d.pixels.len()).step_by(step) {
                let q = d.pixels[k];
                let ray = frame.camera.ray_f64(&frame.c2w, q / out.width, q % out.width);
                let w = d.dist[k] as f64;
                let p = t.to_normalized([0, 1, 2].map(|i| ray.origin[i] + w * ray.direction[i]));
                reach.push(p.iter().fold(0.0f64, |m, v| m.max(v.abs())));
                dist.push(w * scale);
            }
            let med = |v: &mut Vec<f64>| {
                let mid = v.len() / 2;
                *v.select_nth_unstable_by(mid, f64::total_cmp).1
            };
            let (reach, dist) = (med(&mut reach), med(&mut dist));
            if !(reach <= MAX_REACH && dist > near && dist < far) {
                return Err(NerfError::invalid(
                    "loss.depth",
                    format!(
                        "frame `{}`: its depth targets put the surface at {reach:.1} (median, normalised \
                     units; the scene is [-1, 1]^3) and {dist:.3} along the rays (sampled: {near} .. {far}): check \
                     the depth unit (`depth_unit_scale_factor`, `depth_type`) or the points' coordinates",
                        frame.name
                    ),
                ));
            }
        }
        Ok(out)
    }

    fn dense(&mut self, ds: &Dataset, frames: &[usize]) -> NerfResult<()> {
        for &f in frames {
            let frame = &ds.frames[f];
            let Some(mut d) = ds.read_depth(f)? else {
                return Err(NerfError::invalid(
                    "loss.depth.source",
                    format!(
                        "depth_maps, but frame `{}` of {} has no `depth_file_path`",
                        frame.name,
                        ds.transforms_path.display()
                    ),
                ));
            };
            let cam = &frame.camera;
            if ds.depth_is_z {
                if cam.model == CameraModel::OpenCvFisheye {
                    return Err(NerfError::invalid(
                        "loss.depth",
                        format!(
                            "frame `{}`: z-depth maps of fisheye cameras are not supported (use `depth_type: \
                             ray_distance`)",
                            frame.name
                        ),
                    ));
                }
                let w = cam.width as usize;
                for (q, t) in d.iter_mut().enumerate() {
                    let ray = cam.ray_f64(&frame.c2w, (q / w) as u32, (q % w) as u32);
                    *t = (*t as f64 * ray.direction_norm) as f32;
                }
            }
            self.frames
                .insert(f, FrameDepth::from_pairs(d.into_iter().enumerate().map(|(q, d)| (q as u32, d)).collect()));
        }
        Ok(())
    }

    fn sparse(&mut self, ds: &Dataset, frames: &[usize]) -> NerfResult<()> {
        let Some(path) = &ds.sparse_points_path else {
            return Err(NerfError::invalid(
                "loss.depth.source",
                format!("sparse_points, but {} has no `sparse_points_path`", ds.transforms_path.display()),
            ));
        };
        let points = read_sparse_points(ds, path)?;
        let train: std::collections::HashSet<usize> = frames.iter().copied().collect();
        let mut per: HashMap<usize, HashMap<u32, f32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            for &f in p.frames.iter().filter(|f| train.contains(f)) {
                let frame = &ds.frames[f];
                let m = &frame.c2w;
                let rot = [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]);
                let origin = [m[0][3], m[1][3], m[2][3]];
                let Some((row, col, dist)) = project_point(&frame.camera, origin, &rot, p.xyz) else {
                    return Err(NerfError::key(
                        path,
                        format!("points[{i}]"),
                        format!(
                            "{:?} does not project into frame `{}` of its track (behind the camera or outside the \
                             image)",
                            p.xyz, frame.name
                        ),
                    ));
                };
                // Two points on one pixel: the nearer one is the surface the pixel sees.
                let e = per.entry(f).or_default().entry(row * self.width + col).or_insert(f32::INFINITY);
                *e = e.min(dist as f32);
            }
        }
        for (f, m) in per {
            self.frames.insert(f, FrameDepth::from_pairs(m.into_iter().collect()));
        }
        Ok(())
    }

    /// Number of target pixels over all frames.
    pub fn total(&self) -> usize {
        self.counts.values().sum()
    }

    /// Rays of a batch of `r` drawn from target pixels.
    pub fn rays_per_batch(&self, r: usize) -> usize {
        ((self.ray_fraction * r as f64).round() as usize).min(r)
    }

    /// The ray column (distance, sigma) in normalised units for pixel (row, col) of `frame`; (0, 1) without target.
    pub fn column(&self, frame: usize, row: u32, col: u32) -> [f32; 2] {
        match self.frames.get(&frame).and_then(|d| d.get(row * self.width + col)) {
            Some(d) => [(d as f64 * self.scale) as f32, (self.sigma * self.scale) as f32],
            None => [0.0, 1.0],
        }
    }

    /// Draws `n` pixels uniformly among the target pixels of the frames resident in `cache`, with their values.
    pub fn sample_pixels<R: Rng + ?Sized>(&self, cache: &ImageCache, rng: &mut R, n: usize) -> PixelBatch {
        let resident = cache.resident();
        let bands = resident.first().map_or(0, |(_, r)| r.bands);
        let mut out = PixelBatch { bands, ..Default::default() };
        let weights: Vec<usize> = resident.iter().map(|(f, _)| self.counts.get(f).copied().unwrap_or(0)).collect();
        let total: usize = weights.iter().sum();
        if total == 0 {
            return out;
        }
        out.values = vec![0.0; n * bands];
        for s in 0..n {
            let mut k = rng.random_range(0..total);
            let mut i = 0;
            while k >= weights[i] {
                k -= weights[i];
                i += 1;
            }
            let (f, raster) = (&resident[i].0, &resident[i].1);
            let q = self.frames[f].pixels[k];
            let (row, col) = (q / self.width, q % self.width);
            out.image.push(*f as u32);
            out.row.push(row);
            out.col.push(col);
            out.mask.push(raster.mask_at(row, col));
            raster.pixel_into(row, col, &mut out.values[s * bands..(s + 1) * bands]);
        }
        out.values.truncate(out.image.len() * bands);
        out
    }
}
