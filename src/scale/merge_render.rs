//! Renders over blocks (issue 23): `msnerf render BLOCKS`. A view (a source frame, an orbit or a camera path,
//! posed in the world frame) is rendered by every finished block, and each pixel blends the blocks by where their
//! surface for that pixel lies:
//!
//! `w_k(p) = r(d_x) r(d_y)`, `r(d) = clamp(1 - d / m, 0, 1)`,
//!
//! where `p` is the pixel's surface point in block k's render (the median crossing, accumulation >= 0.5; otherwise
//! where the ray meets the partition's ground plane, or the camera when it never does), `d_x`, `d_y` are how far `p`
//! lies outside k's core in the levelled frame on each axis (0 inside, and 0 beyond an outer block's outer edge,
//! whose core reaches to infinity), and `m` is the overlap margin on that side (grown minus core). A point inside
//! one core gets weight 1 from that block, and the neighbours fade out across the overlap, so the seam is a blend
//! over the overlap, not an edge. Colour and accumulation are the weighted means (weights floored at 1e-9, so a
//! pixel no block claims is the plain mean); depth is the weighted mean of the renders that have one.
//!
//! Views are rendered in groups whose accumulators fit `budget_bytes` ((B + 4) float32 and a byte per pixel);
//! each block is loaded once per group.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::error::ScaleError;
use super::merge::finished_runs;
use super::partition::Blocks;
use crate::data::pose::Mat4;
use crate::data::Camera;
use crate::gpu::Context;
use crate::nerf::run::{LoadedRun, RenderedView};
use crate::nerf::views::NovelView;

/// A view posed in the world frame (the dataset's, before any normalisation).
#[derive(Debug, Clone)]
pub struct WorldView {
    /// Output file stem.
    pub name: String,
    pub camera: Camera,
    /// Camera-to-world, OpenGL axes, world frame.
    pub c2w: Mat4,
}

impl WorldView {
    /// The view in `t`'s normalised frame, as one run renders it.
    pub fn normalized(&self, t: &crate::data::PoseTransform) -> NovelView {
        NovelView { name: self.name.clone(), camera: self.camera, c2w: t.pose_to_normalized(&self.c2w) }
    }
}

/// The blend weights of the blocks (see the module docs).
pub struct BlendWeights {
    /// World -> levelled frame.
    rotation: DMat3,
    ground_z: f64,
    /// Per block: core [x0, x1, y0, y1] (outer edges infinite) and margins [x0, x1, y0, y1].
    cores: Vec<([f64; 4], [f64; 4])>,
}

impl BlendWeights {
    pub fn new(blocks: &Blocks) -> BlendWeights {
        let [nx, ny] = blocks.grid;
        let cores = blocks
            .blocks
            .iter()
            .map(|b| {
                let [ix, iy] = b.index;
                let c = b.core;
                let core = [
                    if ix == 0 { f64::NEG_INFINITY } else { c[0] },
                    if ix + 1 == nx { f64::INFINITY } else { c[1] },
                    if iy == 0 { f64::NEG_INFINITY } else { c[2] },
                    if iy + 1 == ny { f64::INFINITY } else { c[3] },
                ];
                let g = b.grown;
                (core, [c[0] - g[0], g[1] - c[1], c[2] - g[2], g[3] - c[3]])
            })
            .collect();
        BlendWeights {
            rotation: DMat3::from_cols_array_2d(&blocks.rotation).transpose(),
            ground_z: blocks.ground_z,
            cores,
        }
    }

    /// Block `k`'s weight for world point `p`.
    pub fn weight(&self, k: usize, p: [f64; 3]) -> f64 {
        let q = self.rotation * DVec3::from(p);
        let (core, margin) = &self.cores[k];
        let ramp = |d: f64, m: f64| {
            if d <= 0.0 {
                1.0
            } else if m > 0.0 {
                (1.0 - d / m).clamp(0.0, 1.0)
            } else {
                0.0
            }
        };
        let wx = if q.x < core[0] { ramp(core[0] - q.x, margin[0]) } else { ramp(q.x - core[1], margin[1]) };
        let wy = if q.y < core[2] { ramp(core[2] - q.y, margin[2]) } else { ramp(q.y - core[3], margin[3]) };
        wx * wy
    }

    /// Where the world ray `o + t d` meets the ground plane (levelled z = ground_z), or `o` when it never does.
    pub fn ground_point(&self, o: [f64; 3], d: [f64; 3]) -> [f64; 3] {
        let (qo, qd) = (self.rotation * DVec3::from(o), self.rotation * DVec3::from(d));
        if qd.z.abs() > 1e-12 {
            let t = (self.ground_z - qo.z) / qd.z;
            if t > 0.0 {
                return [0, 1, 2].map(|i| o[i] + t * d[i]);
            }
        }
        o
    }
}

/// The surface point of pixel `i` of `rv` (rendered through `view`), in the world frame: see the module docs.
pub fn pixel_point(view: &WorldView, rv: &RenderedView, i: usize, weights: &BlendWeights) -> [f64; 3] {
    let (r, c) = ((i / rv.width) as u32, (i % rv.width) as u32);
    let ray = view.camera.ray_f64(&view.c2w, r, c);
    let depth = rv.depth[i] as f64;
    if rv.accumulation[i] >= 0.5 && depth.is_finite() {
        [0, 1, 2].map(|k| ray.origin[k] + ray.direction[k] * depth)
    } else {
        weights.ground_point(ray.origin, ray.direction)
    }
}

/// What the blend did.
#[derive(Debug, Clone, Default)]
pub struct BlendStats {
    /// Blocks rendered, in order.
    pub blocks: Vec<String>,
    /// Blocks left out (`partial`).
    pub missing: Vec<String>,
    /// Pixels (all views) where more than one block had a weight above 0.01.
    pub blended_pixels: usize,
    pub pixels: usize,
}

/// Renders `views` with every finished block of `dir`, blends them and hands each blended view to `sink` (its index
/// in `views`, in order) as soon as its group is done, so host memory holds one group. Blocks without a finished run
/// are refused by name, or left out with `partial`. `progress` gets (block, views of the group done, views in the
/// group).
#[allow(clippy::too_many_arguments)]
pub fn render_blocks(
    ctx: &Context,
    dir: &Path,
    blocks: &Blocks,
    views: &[WorldView],
    partial: bool,
    budget_bytes: usize,
    mut progress: impl FnMut(&str, usize, usize),
    mut sink: impl FnMut(usize, RenderedView) -> Result<(), ScaleError>,
) -> Result<BlendStats, ScaleError> {
    let (runs, missing) = finished_runs(dir, blocks, partial)?;
    let mut stats = BlendStats { missing, ..Default::default() };
    let weights = BlendWeights::new(blocks);
    let mut start = 0;
    let mut nb = None;
    while start < views.len() {
        // The group: as many views as the accumulators' budget allows (at least one).
        let per_pixel = 4 * (nb.unwrap_or(16) + 4) + 1;
        let mut end = start;
        let mut bytes = 0usize;
        while end < views.len() {
            let px = views[end].camera.width as usize * views[end].camera.height as usize;
            if end > start && bytes + px * per_pixel > budget_bytes {
                break;
            }
            bytes += px * per_pixel;
            end += 1;
        }
        let group = &views[start..end];
        let mut acc: Vec<Accumulator> = Vec::new();
        for (k, (b, run)) in blocks.blocks.iter().zip(&runs).enumerate() {
            let Some(run) = run else { continue };
            let fail = |e: &dyn std::fmt::Display| ScaleError::Block { block: b.name.clone(), reason: e.to_string() };
            let mut loaded = LoadedRun::load(ctx, run).map_err(|e| fail(&e))?;
            let bands = loaded.ds.n_bands();
            if *nb.get_or_insert(bands) != bands {
                return Err(fail(&format!("{bands} bands, the other blocks {}", nb.unwrap_or(0))));
            }
            let novel: Vec<NovelView> = group.iter().map(|v| v.normalized(&loaded.transform)).collect();
            loaded.set_novel_views(&novel).map_err(|e| fail(&e))?;
            if start == 0 {
                stats.blocks.push(b.name.clone());
            }
            for (j, v) in group.iter().enumerate() {
                let rv = loaded.render_novel_view(j).map_err(|e| fail(&e))?;
                if acc.len() <= j {
                    acc.push(Accumulator::new(rv.width, rv.height, bands));
                }
                acc[j].add(&rv, |i| weights.weight(k, pixel_point(v, &rv, i, &weights)));
                progress(&b.name, j + 1, group.len());
            }
        }
        for (j, a) in acc.into_iter().enumerate() {
            stats.blended_pixels += a.blended;
            stats.pixels += a.width * a.height;
            sink(start + j, a.finish(start + j))?;
        }
        start = end;
    }
    Ok(stats)
}

/// Weighted sums of one view's renders.
struct Accumulator {
    width: usize,
    height: usize,
    bands: usize,
    colour: Vec<f32>,
    accumulation: Vec<f32>,
    depth: Vec<f32>,
    weight: Vec<f32>,
    /// The weights of the renders with a finite depth.
    depth_weight: Vec<f32>,
    /// Pixels with a weight above 0.01 so far, per pixel (to count blended ones).
    claims: Vec<u8>,
    blended: usize,
    seconds: f64,
}

impl Accumulator {
    fn new(width: usize, height: usize, bands: usize) -> Accumulator {
        let n = width * height;
        Accumulator {
            width,
            height,
            bands,
            colour: vec![0.0; n * bands],
            accumulation: vec![0.0; n],
            depth: vec![0.0; n],
            weight: vec![0.0; n],
            depth_weight: vec![0.0; n],
            claims: vec![0; n],
            blended: 0,
            seconds: 0.0,
        }
    }

    fn add(&mut self, rv: &RenderedView, weight: impl Fn(usize) -> f64) {
        let nb = self.bands;
        for i in 0..self.width * self.height {
            let w = weight(i);
            if w > 0.01 {
                self.claims[i] = self.claims[i].saturating_add(1);
                if self.claims[i] == 2 {
                    self.blended += 1;
                }
            }
            let w = w.max(1e-9) as f32;
            for b in 0..nb {
                self.colour[i * nb + b] += w * rv.colour[i * nb + b];
            }
            self.accumulation[i] += w * rv.accumulation[i];
            let d = rv.depth[i];
            if d.is_finite() {
                self.depth[i] += w * d;
                self.depth_weight[i] += w;
            }
            self.weight[i] += w;
        }
        self.seconds += rv.seconds;
    }

    fn finish(mut self, frame: usize) -> RenderedView {
        let nb = self.bands;
        for (i, &w) in self.weight.iter().enumerate() {
            for b in 0..nb {
                self.colour[i * nb + b] /= w;
            }
            self.accumulation[i] /= w;
            let dw = self.depth_weight[i];
            self.depth[i] = if dw > 0.0 { self.depth[i] / dw } else { f32::NAN };
        }
        RenderedView {
            frame,
            width: self.width,
            height: self.height,
            colour: self.colour,
            accumulation: self.accumulation,
            depth: self.depth,
            seconds: self.seconds,
        }
    }
}
