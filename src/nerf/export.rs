//! Multispectral point clouds from a trained run (nerfstudio `ns-export pointcloud`, spec/nerfacto.md §6.7, made
//! careful as a multi-view-stereo fusion step; docs/geometry.md).
//!
//! 1. Render random training pixels; a ray gives a point at its **median depth** (the exact crossing of
//!    accumulation 0.5 inside its interval, `glsl/render/composite.comp`) and every band's value there.
//! 2. Keep rays whose accumulation passes `min_accumulation`.
//! 3. **Spread filter** (`max_spread_cells`): the depth quantiles q25 and q75 of the ray's weights give the
//!    interquartile spread; a ray whose weights spread over more than that many cells of the field's finest
//!    hash-grid level (at the point, with the contraction's stretch outside the unit cube) has no single surface and
//!    is dropped.
//! 4. **Multi-view consistency** ([`Consistency`]): the point is projected into up to `views` other training views
//!    that see it (in front, inside the image), spread evenly over the candidates; each renders the ray through that
//!    pixel, and a view *agrees* when its median depth matches the distance to the point within `tolerance`
//!    pixel footprints (footprint = distance / focal length). A point needs `min_agree` agreeing views (COLMAP's
//!    stereo fusion keeps a pixel seen consistently by >= `min_num_pixels` views in the same way).
//! 5. **Scene box** (`scene_box`): with the aerial normalisation, points outside its unit cube (more than half
//!    the cube's half-size below the ground, or beyond the footprint) are dropped, as nerfstudio's export crops to
//!    its scene box; with `poses` the cube is centred on the cameras and nothing is cropped.
//! 6. **Photometric refinement** (`refine`, on by default; [`super::refine`]): each consistent point is searched
//!    along its ray against the training images of its agreeing views; it moves where the correlation is strong,
//!    keeps the field's position where it is weak, and is dropped where the images do not support it.
//! 7. Per-point confidence as scalar fields: `accumulation`, `depth_spread` (q75 - q25 in world units),
//!    `agreeing_views`, `checked_views`, and with the refinement `photo_ncc` and `photo_shift`.
//!
//! Positions go back to the dataset's own world frame and units. With `normals`, each point also gets the density
//! field's normal there ([`super::normals`]), facing the camera that saw it, rotated back into the world frame.
//! [`ExportOptions::legacy`] is the earlier behaviour (steps 1-2 only), kept for comparison.

use super::error::{NerfError, NerfResult};
use super::normals::{density_gradients, normal_from_gradient};
use super::refine::RefineOptions;
use super::refine_points::{refine_points, FrameStore, RefinePoint, RefineStats};
use super::run::LoadedRun;
use crate::data::{camera, Split};
use crate::output::pointcloud::PointCloud;
use rand::{Rng, SeedableRng};

/// The multi-view consistency check.
#[derive(Clone, Debug, PartialEq)]
pub struct Consistency {
    /// Other training views checked per point (at most).
    pub views: usize,
    /// Agreeing views a point needs.
    pub min_agree: usize,
    /// Largest |rendered depth - distance| for agreement, in pixel footprints of the checking view.
    pub tolerance: f64,
}

impl Default for Consistency {
    fn default() -> Self {
        Self { views: 6, min_agree: 2, tolerance: 2.0 }
    }
}

#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Points to draw before filtering.
    pub rays: usize,
    /// Minimum accumulation (opacity) of a ray for its point to be kept.
    pub min_accumulation: f32,
    pub seed: u64,
    /// Also compute each point's surface normal from the density field.
    pub normals: bool,
    /// Drop rays whose weights' interquartile spread exceeds this many finest field cells (None: off).
    pub max_spread_cells: Option<f64>,
    /// Multi-view consistency (None: off).
    pub consistency: Option<Consistency>,
    /// Drop points outside the unit cube when the run used the aerial normalisation (its cube is the region of
    /// interest; nerfstudio's `ns-export pointcloud` crops to the same box by default). No effect with `poses`.
    pub scene_box: bool,
    /// Photometric refinement of each consistent point along its ray against the training images
    /// ([`super::refine`]; needs `consistency`, whose agreeing views are the partners). On by default; None keeps
    /// the field's surface, which sits up to a metre above flat ground on the campus (docs/geometry.md).
    pub refine: Option<RefineOptions>,
    /// Host bytes of decoded training images the refinement may hold (`process` passes the training's cache
    /// budget from the planner, so every stage of a flight stays within one host budget).
    pub image_budget_bytes: u64,
}

/// Host memory the refinement may hold in decoded training images unless the caller says otherwise.
pub const REFINE_IMAGE_BUDGET: u64 = 4 << 30;

/// The spread filter's default: rays whose weights spread over more finest-grid cells than this are dropped.
pub const DEFAULT_MAX_SPREAD_CELLS: f64 = 8.0;

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            rays: 200_000,
            min_accumulation: 0.5,
            seed: 42,
            normals: false,
            max_spread_cells: Some(DEFAULT_MAX_SPREAD_CELLS),
            consistency: Some(Consistency::default()),
            scene_box: true,
            refine: Some(RefineOptions::default()),
            image_budget_bytes: REFINE_IMAGE_BUDGET,
        }
    }
}

impl ExportOptions {
    /// The earlier export: accumulation threshold only, no spread or consistency filter.
    pub fn legacy(rays: usize, min_accumulation: f32, seed: u64) -> Self {
        Self {
            rays,
            min_accumulation,
            seed,
            normals: false,
            max_spread_cells: None,
            consistency: None,
            scene_box: false,
            refine: None,
            image_budget_bytes: REFINE_IMAGE_BUDGET,
        }
    }
}

/// What each filter removed (for the command's summary).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExportStats {
    pub rays: usize,
    pub below_accumulation: usize,
    pub spread: usize,
    pub inconsistent: usize,
    /// Points outside the aerial normalisation's unit cube ([`ExportOptions::scene_box`]).
    pub outside_box: usize,
    pub kept: usize,
    /// Rays rendered for the consistency check.
    pub check_rays: usize,
    /// Points dropped without photometric support ([`RefineOptions::drop_unsupported`]).
    pub unsupported: usize,
    /// What the photometric refinement did (None: off).
    pub refine: Option<RefineStats>,
}

/// Size of one cell of the finest hash-grid level at normalised point `p`: 4 / max_resolution in contracted
/// coordinates, stretched by the L-infinity contraction's radial derivative (m^2 at |p|_inf = m > 1).
pub fn field_cell_size(p: [f64; 3], max_resolution: u32, contraction: bool) -> f64 {
    let m = p.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if contraction {
        4.0 / max_resolution as f64 * m.max(1.0).powi(2)
    } else {
        2.0 / max_resolution as f64
    }
}

/// One candidate point before the consistency check.
struct Candidate {
    frame: usize,
    p: [f64; 3],
    dir: [f64; 3],
    accumulation: f32,
    spread: f64,
    ray: usize,
}

/// Renders random training pixels and returns the kept points (world frame) with their band values.
pub fn export_points(run: &mut LoadedRun, opts: &ExportOptions) -> NerfResult<PointCloud> {
    export_points_with_stats(run, opts).map(|(c, _)| c)
}

/// [`export_points`] and what each filter removed.
pub fn export_points_with_stats(run: &mut LoadedRun, opts: &ExportOptions) -> NerfResult<(PointCloud, ExportStats)> {
    let frames = run.ds.split_indices(Split::Train);
    if frames.is_empty() {
        return Err(NerfError::key(&run.ds.transforms_path, "frames", "no training frames to export from"));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed);
    let (w, h) = (run.ds.width, run.ds.height);
    let mut pixels = Vec::with_capacity(opts.rays * 3);
    for _ in 0..opts.rays {
        pixels.extend([
            frames[rng.random_range(0..frames.len())] as u32,
            rng.random_range(0..h),
            rng.random_range(0..w),
        ]);
    }
    let out = run.pipe.render(&pixels).map_err(NerfError::gpu("rendering export rays"))?;
    let mut stats = ExportStats { rays: opts.rays, ..Default::default() };
    let max_res = run.cfg.field.grid.max_resolution;
    let contraction = run.cfg.sampling.scene_contraction;
    // Below accumulation 0.5 the median is the last sample's midpoint, not a surface: the careful export never keeps
    // such a ray, whatever `min_accumulation` says.
    let careful = opts.max_spread_cells.is_some() || opts.consistency.is_some();
    let crop_to_box = opts.scene_box && run.ds.aerial_normalization();
    let floor = if careful { opts.min_accumulation.max(0.5) } else { opts.min_accumulation };
    let mut cands: Vec<Candidate> = Vec::new();
    for i in 0..opts.rays {
        if out.accumulation[i] < floor || !out.median_depth[i].is_finite() {
            stats.below_accumulation += 1;
            continue;
        }
        let (f, row, col) = (pixels[3 * i] as usize, pixels[3 * i + 1], pixels[3 * i + 2]);
        let c2w = run.transform.pose_to_normalized(&run.ds.frames[f].c2w);
        let ray = run.ds.frames[f].camera.ray_f64(&c2w, row, col);
        let t = out.median_depth[i] as f64;
        let p = [0, 1, 2].map(|k| ray.origin[k] + ray.direction[k] * t);
        if crop_to_box && p.iter().any(|v| v.abs() > 1.0) {
            stats.outside_box += 1;
            continue;
        }
        let spread = (out.depth_q75[i] - out.depth_q25[i]) as f64;
        if let Some(max_cells) = opts.max_spread_cells {
            let limit = max_cells * field_cell_size(p, max_res, contraction);
            if spread.is_nan() || spread > limit {
                stats.spread += 1;
                continue;
            }
        }
        let spread = spread.max(0.0);
        cands.push(Candidate { frame: f, p, dir: ray.direction, accumulation: out.accumulation[i], spread, ray: i });
    }
    let (agree, checked, agreeing) = match &opts.consistency {
        Some(c) => {
            let points: Vec<([f64; 3], usize)> = cands.iter().map(|c| (c.p, c.frame)).collect();
            let v = consistency(run, &frames, &points, c)?;
            stats.check_rays = v.rays;
            (v.agree, v.checked, v.agreeing)
        }
        None => (vec![0; cands.len()], vec![0; cands.len()], vec![Vec::new(); cands.len()]),
    };
    let min_agree = opts.consistency.as_ref().map_or(0, |c| c.min_agree);
    let mut photo = vec![(0.0f64, f64::NAN, true); cands.len()];
    if let Some(r) = &opts.refine {
        if opts.consistency.is_none() {
            return Err(NerfError::invalid("photometric refinement", "needs the multi-view consistency check"));
        }
        let keep: Vec<usize> = (0..cands.len()).filter(|&k| agree[k] as usize >= min_agree).collect();
        let mut pts: Vec<RefinePoint> = keep
            .iter()
            .map(|&k| RefinePoint {
                p: cands[k].p,
                dir: cands[k].dir,
                frame: cands[k].frame,
                partners: agreeing[k].clone(),
            })
            .collect();
        let (res, rs) = refine_points(run, &mut pts, r, &mut FrameStore::new(opts.image_budget_bytes))?;
        // A skipped refinement (no band through the frame camera) leaves every point as the field put it.
        if rs.skipped.is_none() {
            for ((&k, pt), res) in keep.iter().zip(&pts).zip(&res) {
                cands[k].p = pt.p;
                photo[k] = (res.shift, res.ncc, res.supported);
            }
        }
        stats.refine = Some(RefineStats { median_shift: rs.median_shift / run.transform.scale, ..rs });
    }
    let bands = run.ds.bands.clone();
    let b = bands.len();
    let (mut positions, mut normalised, mut view_dirs, mut values) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut acc_attr, mut spread_attr, mut agree_attr, mut checked_attr) = (vec![], vec![], vec![], vec![]);
    let (mut ncc_attr, mut shift_attr) = (vec![], vec![]);
    let inv_scale = 1.0 / run.transform.scale;
    for (k, c) in cands.iter().enumerate() {
        if let Some(cfg) = &opts.consistency {
            if (agree[k] as usize) < cfg.min_agree {
                stats.inconsistent += 1;
                continue;
            }
        }
        if opts.refine.as_ref().is_some_and(|r| r.drop_unsupported) && !photo[k].2 {
            stats.unsupported += 1;
            continue;
        }
        positions.push(run.transform.to_world(c.p));
        normalised.push(c.p);
        view_dirs.push(c.dir);
        values.extend_from_slice(&out.colour[c.ray * b..(c.ray + 1) * b]);
        acc_attr.push(c.accumulation);
        spread_attr.push((c.spread * inv_scale) as f32);
        agree_attr.push(agree[k] as f32);
        checked_attr.push(checked[k] as f32);
        ncc_attr.push(photo[k].1 as f32);
        shift_attr.push((photo[k].0 * inv_scale) as f32);
    }
    stats.kept = positions.len();
    let mut cloud = PointCloud::new(positions, bands, values)?;
    let attr = |cloud: &mut PointCloud, name: &str, what: &str, v: Vec<f32>| {
        cloud.add_attribute(name, what, v).map_err(NerfError::from)
    };
    attr(&mut cloud, "accumulation", "ray opacity", acc_attr)?;
    attr(&mut cloud, "depth_spread", "q75-q25 of ray weights", spread_attr)?;
    if opts.consistency.is_some() {
        attr(&mut cloud, "agreeing_views", "views whose depth agrees", agree_attr)?;
        attr(&mut cloud, "checked_views", "views that see the point", checked_attr)?;
    }
    if opts.refine.is_some() {
        attr(&mut cloud, "photo_ncc", "best mean NCC of the refinement", ncc_attr)?;
        attr(&mut cloud, "photo_shift", "refinement shift along the ray", shift_attr)?;
    }
    if opts.normals {
        let grads = density_gradients(&run.pipe.ctx, &run.pipe.model, &normalised)
            .map_err(NerfError::gpu("density normals"))?;
        let normals = grads
            .iter()
            .zip(&view_dirs)
            .map(|(&g, &d)| {
                // A vanishing gradient (empty space) has no normal: written as (0, 0, 0).
                normal_from_gradient(g, d).map_or([0.0; 3], |n| run.transform.direction_to_world(n).map(|v| v as f32))
            })
            .collect();
        cloud.normals = Some(normals);
    }
    Ok((cloud, stats))
}

/// A training view in the normalised frame, ready for projection.
struct View {
    frame: usize,
    origin: [f64; 3],
    /// Rows of the camera-to-world rotation (columns are the camera axes).
    rot: [[f64; 3]; 3],
    cam: crate::data::Camera,
}

impl View {
    fn project(&self, p: [f64; 3]) -> Option<(u32, u32, f64)> {
        camera::project_point(&self.cam, self.origin, &self.rot, p)
    }
}

/// The consistency check's outcome per point.
pub struct Votes {
    /// Agreeing views per point.
    pub agree: Vec<u32>,
    /// Checked views per point.
    pub checked: Vec<u32>,
    /// Rays rendered.
    pub rays: usize,
    /// The agreeing frames of each point (the photometric refinement's partners).
    pub agreeing: Vec<Vec<u32>>,
}

/// Multi-view consistency votes for normalised-frame points, each with the frame that produced it (left out of its
/// check; `usize::MAX` for none): per point the agreeing and the checked views among `frames`, the agreeing frames,
/// and the number of rays rendered. See [`Consistency`].
pub fn consistency(
    run: &mut LoadedRun,
    frames: &[usize],
    cands: &[([f64; 3], usize)],
    c: &Consistency,
) -> NerfResult<Votes> {
    let views: Vec<View> = frames
        .iter()
        .map(|&f| {
            let m = run.transform.pose_to_normalized(&run.ds.frames[f].c2w);
            View {
                frame: f,
                origin: [m[0][3], m[1][3], m[2][3]],
                rot: [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]),
                cam: run.ds.frames[f].camera,
            }
        })
        .collect();
    // Checks: (candidate, distance, focal) per rendered pixel.
    let mut pixels = Vec::new();
    let mut checks: Vec<(u32, f64, f64)> = Vec::new();
    let mut checked = vec![0u32; cands.len()];
    let mut seen = Vec::new();
    for (k, &(p, own)) in cands.iter().enumerate() {
        seen.clear();
        seen.extend(views.iter().filter(|v| v.frame != own).filter_map(|v| v.project(p).map(|x| (v, x))));
        let n = seen.len().min(c.views);
        for j in 0..n {
            // Evenly spread over the candidates (wide baselines test the surface hardest).
            let (v, (row, col, dist)) = seen[j * seen.len() / n];
            pixels.extend([v.frame as u32, row, col]);
            checks.push((k as u32, dist, 0.5 * (v.cam.fx + v.cam.fy)));
        }
        checked[k] = n as u32;
    }
    let mut agree = vec![0u32; cands.len()];
    let mut agreeing = vec![Vec::new(); cands.len()];
    if checks.is_empty() {
        return Ok(Votes { agree, checked, rays: 0, agreeing });
    }
    let out = run.pipe.render(&pixels).map_err(NerfError::gpu("rendering consistency rays"))?;
    for (i, &(k, dist, focal)) in checks.iter().enumerate() {
        let d = out.median_depth[i] as f64;
        if (d - dist).abs() <= c.tolerance * dist / focal {
            agree[k as usize] += 1;
            agreeing[k as usize].push(pixels[3 * i]);
        }
    }
    Ok(Votes { agree, checked, rays: checks.len(), agreeing })
}
