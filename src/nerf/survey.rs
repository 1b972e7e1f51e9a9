//! Survey products from a trained run (issue 21): a digital surface model and a multispectral true orthomosaic on
//! one north-up grid in the dataset's world frame (so in its `crs`).
//!
//! Every grid cell is one **vertical ray**: an orthographic camera (`CameraModel::Orthographic`, parallel rays along
//! world -z) looks straight down from `top` (default: the training cameras' median height, so the rays start in air
//! the training rays crossed), one pixel per cell centre. Per ray:
//! - **height**: the careful depth of the point-cloud export ([`super::export`]): the exact crossing of
//!   accumulation 0.5, mapped back to world z. The cell is nodata when the field is not confident there: accumulation
//!   below `min_accumulation` (at least 0.5), a surface outside the aerial normalisation's unit cube (the region of
//!   interest, as the point-cloud export crops), weights spread over more than `max_spread_cells` finest-grid cells,
//!   or (with [`Consistency`]) fewer than `min_agree` training views whose own depth agrees with the point; then
//!   (with `refine`, the default) refined photometrically along the vertical as the export refines its points;
//! - **band values**: the composited colour of the same ray, so seen from straight above: the colour head is
//!   evaluated with the nadir view direction and the training cameras' mean appearance embedding (nerfstudio's
//!   evaluation convention). View dependence is not averaged away: a nadir flight's images see most surfaces from
//!   near-nadir, which is what the ortho shows. Nodata only where accumulation is below the floor (the colour of an
//!   empty ray is the background's, not the surface's).
//!
//! Every DSM cell gets a [`quality`] code: measured (the refinement placed or confirmed its height, and a second
//! sweep from another reference found the same height: [`super::cross_check`]), the field's height only, or a gap
//! (a surface the filters turned down); [`DsmFill`] then decides what the DSM makes of the
//! unsupported cells and gaps (`super::survey_products::finish_dsm`), and the codes are written beside it.
//!
//! The grid is rendered in blocks of whole rows (at most [`SurveyOptions::block_rays`] rays each, consistency rays
//! included in the bound); each block goes to a sink (the GeoTIFF writers), so host memory stays bounded whatever the
//! raster size.

use super::cross_check;
use super::export::{consistency, field_cell_size, Consistency, REFINE_IMAGE_BUDGET};
use super::refine::{holds_sweep, RefineOptions};
use super::refine_points::{normalised_poses, refine_points, FrameStore, PointResult, RefinePoint};
use super::run::LoadedRun;
use super::views::NovelView;
use crate::data::{Camera, CameraModel, Distortion, Split};

/// A failed survey export, naming the option or the stage.
#[derive(Debug, thiserror::Error)]
pub enum SurveyError {
    /// An option is out of range; `what` names it.
    #[error("{what}: {reason}")]
    Invalid { what: String, reason: String },
    /// Rendering failed.
    #[error("rendering the survey grid: {0}")]
    Render(#[from] super::error::NerfError),
    /// Writing a product failed.
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
}

impl SurveyError {
    fn invalid(what: &str, reason: impl std::fmt::Display) -> Self {
        SurveyError::Invalid { what: what.into(), reason: reason.to_string() }
    }
}

/// A north-up grid in the dataset's world frame: `origin` is (x, y) of the top-left corner of the top-left cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurveyGrid {
    pub origin: [f64; 2],
    pub gsd: f64,
    pub width: usize,
    pub height: usize,
}

impl SurveyGrid {
    /// World x, y of the centre of cell (row, col).
    pub fn centre(&self, row: usize, col: usize) -> [f64; 2] {
        [self.origin[0] + (col as f64 + 0.5) * self.gsd, self.origin[1] - (row as f64 + 0.5) * self.gsd]
    }

    /// `[xmin, ymin, xmax, ymax]` of the cells' outer edges.
    pub fn bounds(&self) -> [f64; 4] {
        [
            self.origin[0],
            self.origin[1] - self.height as f64 * self.gsd,
            self.origin[0] + self.width as f64 * self.gsd,
            self.origin[1],
        ]
    }

    pub fn cells(&self) -> usize {
        self.width * self.height
    }

    /// The grid of `gsd` cells covering `bounds` (`[xmin, ymin, xmax, ymax]`), its edges snapped outward to whole
    /// multiples of `gsd` (so exports of one area at one GSD share their grid); refused when empty or larger than
    /// `max_cells`, with the numbers.
    pub fn covering(bounds: [f64; 4], gsd: f64, max_cells: usize) -> Result<SurveyGrid, SurveyError> {
        if !(gsd.is_finite() && gsd > 0.0) {
            return Err(SurveyError::invalid("gsd", format!("must be a positive number of metres, got {gsd}")));
        }
        let [x0, y0, x1, y1] = bounds;
        if !bounds.iter().all(|v| v.is_finite()) || x1 <= x0 || y1 <= y0 {
            return Err(SurveyError::invalid(
                "bounds",
                format!("xmin,ymin,xmax,ymax = {x0},{y0},{x1},{y1} is empty (it needs xmax > xmin and ymax > ymin)"),
            ));
        }
        let left = (x0 / gsd).floor() * gsd;
        let top = (y1 / gsd).ceil() * gsd;
        let width = ((x1 - left) / gsd - 1e-9).ceil().max(1.0);
        let height = ((top - y0) / gsd - 1e-9).ceil().max(1.0);
        let cells = width * height;
        if cells > max_cells as f64 {
            return Err(SurveyError::invalid(
                "gsd",
                format!(
                    "{gsd} m over {:.1} x {:.1} m makes {width} x {height} = {cells:.3e} cells, more than the limit of \
                     {max_cells} (give a larger --gsd, smaller --bounds, or raise --max-cells)",
                    x1 - x0,
                    y1 - y0
                ),
            ));
        }
        Ok(SurveyGrid { origin: [left, top], gsd, width: width as usize, height: height as usize })
    }
}

/// What a DSM cell's height rests on: the codes of the quality raster written beside the DSM.
pub mod quality {
    /// No height (the raster's nodata).
    pub const NODATA: u8 = 0;
    /// The images support the height (the photometric refinement placed or confirmed it).
    pub const MEASURED: u8 = 1;
    /// Interpolated from measured cells around it ([`super::DsmFill::Interpolate`]).
    pub const INTERPOLATED: u8 = 2;
    /// The field's height, which no image confirmed (refinement off, or [`super::DsmFill::Field`]).
    pub const FIELD_ONLY: u8 = 3;
    /// A surface the DSM's filters turned down (spread, consistency): a gap to fill, never written as such.
    pub const GAP: u8 = 4;
    /// The codes written to a quality raster, with their names.
    pub const NAMES: [(u8, &str); 3] =
        [(MEASURED, "measured"), (INTERPOLATED, "interpolated"), (FIELD_ONLY, "field only")];
}

/// What the DSM does with cells the images do not support.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DsmFill {
    /// The default. Cells without photometric support are interpolated as `interpolate` does where the field's
    /// height lies within `fill_tolerance` of the interpolation (a uniform lawn, a pond, a sports field: the field
    /// adds only its error there) and keep the field's height where it stands out (a crown or a wall a plane patch
    /// cannot place, which interpolation would flatten). Gaps (surfaces the filters turned down) are interpolated
    /// unless the interpolation lies more than `fill_tolerance` above the field's height there: the field errs
    /// upwards (floaters), and an interpolation above it bridges a step down (from a roof over the foot of its wall).
    #[default]
    Auto,
    /// Interpolated from the measured cells around them (inverse distance, eight directions, up to a distance,
    /// never across a step steeper than 45 degrees): a flat, textureless field comes out at the height of its
    /// supported edges; farther cells and steps stay nodata.
    Interpolate,
    /// The field's own height (it may sit above a surface it could not see texture on); gaps stay nodata.
    Field,
    /// Nodata.
    None,
}

/// Default distance up to which [`DsmFill::Interpolate`] reaches, in cells.
pub const FILL_MAX_CELLS: f64 = 100.0;

/// Default [`SurveyOptions::fill_tolerance`], in world units (metres in a projected CRS): half the lowest tree
/// `export trees` counts, above the field's error on open ground.
pub const FILL_TOLERANCE: f64 = 1.0;

/// What to render and how to judge it.
#[derive(Debug, Clone)]
pub struct SurveyOptions {
    /// Minimum accumulation of a cell's ray (raised to 0.5: below it there is no median crossing).
    pub min_accumulation: f32,
    /// Drop cells whose weights' interquartile spread exceeds this many finest-grid cells (None: off).
    pub max_spread_cells: Option<f64>,
    /// Multi-view consistency of the DSM's points (None: off).
    pub consistency: Option<Consistency>,
    /// Drop DSM points outside the unit cube when the run used the aerial normalisation. No effect with `poses`.
    pub scene_box: bool,
    /// World z the vertical rays start from (None: the training cameras' median height).
    pub top: Option<f64>,
    /// Rays rendered per block, consistency rays included (bounds host memory).
    pub block_rays: usize,
    /// Photometric refinement of each consistent cell's height against the training images (needs `consistency`;
    /// see [`super::refine`]). On by default, as for the point cloud, but a cell without photometric support keeps
    /// the field's height (a DSM with holes over every uniform surface is not what a survey wants); None: the
    /// field's heights everywhere.
    pub refine: Option<RefineOptions>,
    /// Cells without photometric support (and surfaces the filters turned down) in the DSM.
    pub fill: DsmFill,
    /// How far [`DsmFill::Interpolate`] reaches, in world units (None: [`FILL_MAX_CELLS`] cells).
    pub fill_max_distance: Option<f64>,
    /// How close the field's height must lie to the interpolation for [`DsmFill::Auto`] to take the interpolation,
    /// in world units.
    pub fill_tolerance: f64,
    /// Host bytes of decoded training images the refinement may hold (as [`super::export::ExportOptions`]).
    pub image_budget_bytes: u64,
}

/// Grids with more cells than this are refused unless asked for (`--max-cells`).
pub const MAX_SURVEY_CELLS: usize = 200_000_000;

impl Default for SurveyOptions {
    fn default() -> Self {
        Self {
            min_accumulation: 0.5,
            max_spread_cells: Some(crate::nerf::export::DEFAULT_MAX_SPREAD_CELLS),
            consistency: Some(Consistency::default()),
            scene_box: true,
            top: None,
            block_rays: 1 << 20,
            refine: Some(RefineOptions::dsm()),
            fill: DsmFill::default(),
            fill_max_distance: None,
            fill_tolerance: FILL_TOLERANCE,
            image_budget_bytes: REFINE_IMAGE_BUDGET,
        }
    }
}

/// What the filters did, over the whole grid.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SurveyStats {
    pub cells: usize,
    /// Cells with a height.
    pub valid: usize,
    /// Cells whose ray stayed below the accumulation floor (nodata in both products).
    pub no_surface: usize,
    /// Cells whose surface lies outside the region of interest (DSM only).
    pub outside_box: usize,
    /// Cells dropped by the spread filter (DSM only).
    pub spread: usize,
    /// Cells dropped by the consistency check (DSM only).
    pub inconsistent: usize,
    /// Cells whose height the photometric refinement moved (DSM only).
    pub refined: usize,
    /// Cells without photometric support, nodata unless the refinement keeps them (DSM only; the cross-check's
    /// unconfirmed cells among them).
    pub unsupported: usize,
    /// Cells one sweep supported that the cross-check's second sweep did not confirm (DSM only).
    pub unconfirmed: usize,
    /// Of the DSM's cells with a height: measured (photometric support), interpolated, the field's height only.
    pub measured: usize,
    pub interpolated: usize,
    pub field_only: usize,
    /// Rays rendered, consistency rays included.
    pub rays: usize,
    /// World z the vertical rays started from.
    pub top: f64,
    pub seconds: f64,
}

impl SurveyStats {
    /// The DSM's cells by what their heights rest on, as one line (the commands and the process report print it).
    pub fn quality_line(&self) -> String {
        let pct = |n: usize| 100.0 * n as f64 / self.cells.max(1) as f64;
        format!(
            "DSM cells: {:.1} % measured (photometric support), {:.1} % interpolated, {:.1} % field only, {:.1} % nodata",
            pct(self.measured),
            pct(self.interpolated),
            pct(self.field_only),
            pct(self.cells.saturating_sub(self.valid))
        )
    }
}

/// One block of whole grid rows, as the sinks receive it.
pub struct RowBlock {
    /// First grid row of the block.
    pub row0: usize,
    pub rows: usize,
    /// rows x width heights (world z), NaN where nodata; a [`quality::GAP`] cell holds the field's height it was
    /// turned down with (NaN when unknown), which the DSM's fill may consult but never writes.
    pub height: Vec<f32>,
    /// rows x width x B band values (pixel-interleaved), NaN where nodata.
    pub values: Vec<f32>,
    /// rows x width [`quality`] codes of the heights.
    pub quality: Vec<u8>,
}

/// The ground the training cameras saw, `[xmin, ymin, xmax, ymax]` in world units. The ground height is the median
/// height of the surface under the training images' centre pixels; a ring of rays along every training image's
/// border is cut with that plane (hits farther than 10 flight heights from their camera are pulled in to that
/// distance, as the aerial normalisation does), and the bounds are the 2nd-98th percentile box of the hits. With the
/// aerial normalisation the box is then clipped to the footprint of its unit cube (the region of interest).
pub fn seen_bounds(run: &mut LoadedRun) -> Result<[f64; 4], SurveyError> {
    let frames = run.ds.split_indices(Split::Train);
    let (w, h) = (run.ds.width, run.ds.height);
    // 1. Ground height from the centre pixels.
    let pixels: Vec<u32> = frames.iter().flat_map(|&f| [f as u32, h / 2, w / 2]).collect();
    let out = run.pipe.render(&pixels).map_err(super::error::NerfError::gpu("the survey rays"))?;
    let mut zs = Vec::new();
    for (k, &f) in frames.iter().enumerate() {
        if out.accumulation[k] < 0.5 || !out.median_depth[k].is_finite() {
            continue;
        }
        let c2w = run.transform.pose_to_normalized(&run.ds.frames[f].c2w);
        let ray = run.ds.frames[f].camera.ray_f64(&c2w, h / 2, w / 2);
        let p = [0, 1, 2].map(|i| ray.origin[i] + ray.direction[i] * out.median_depth[k] as f64);
        zs.push(run.transform.to_world(p)[2]);
    }
    if zs.is_empty() {
        return Err(SurveyError::invalid(
            "bounds",
            "no training image's centre ray reaches a surface: the field has no ground to map (give --bounds)",
        ));
    }
    let ground = crate::util::stats::median(&zs);
    // 2. Border rays cut with the ground plane.
    let steps = 8u32;
    let mut ring: Vec<(u32, u32)> = Vec::new();
    for k in 0..=steps {
        let (c, r) = ((w - 1) * k / steps, (h - 1) * k / steps);
        ring.extend([(0, c), (h - 1, c), (r, 0), (r, w - 1)]);
    }
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for &f in &frames {
        let frame = &run.ds.frames[f];
        for &(r, c) in &ring {
            let ray = frame.camera.ray_f64(&frame.c2w, r, c);
            let above = ray.origin[2] - ground;
            if above <= 0.0 {
                continue;
            }
            let reach = 10.0 * above;
            let t = if ray.direction[2] < -1e-6 { (-above / ray.direction[2]).min(reach) } else { reach };
            let horizontal = (ray.direction[0].powi(2) + ray.direction[1].powi(2)).sqrt().max(1e-12);
            let t = t.min(reach / horizontal);
            xs.push(ray.origin[0] + t * ray.direction[0]);
            ys.push(ray.origin[1] + t * ray.direction[1]);
        }
    }
    if xs.len() < 4 {
        return Err(SurveyError::invalid("bounds", "the training cameras are not above the ground (give --bounds)"));
    }
    let pct = |v: &mut Vec<f64>, p: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * p).round() as usize]
    };
    let mut b = [pct(&mut xs, 0.02), pct(&mut ys, 0.02), pct(&mut xs, 0.98), pct(&mut ys, 0.98)];
    // 3. The aerial normalisation's region of interest.
    if run.ds.aerial_normalization() {
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|k| run.transform.to_world([0, 1, 2].map(|a| if k >> a & 1 == 1 { 1.0 } else { -1.0 })))
            .collect();
        let lo = |a: usize| corners.iter().map(|c| c[a]).fold(f64::MAX, f64::min);
        let hi = |a: usize| corners.iter().map(|c| c[a]).fold(f64::MIN, f64::max);
        b = [b[0].max(lo(0)), b[1].max(lo(1)), b[2].min(hi(0)), b[3].min(hi(1))];
    }
    Ok(b)
}

/// The training cameras' median height (world z).
pub fn median_camera_height(run: &LoadedRun) -> f64 {
    training_camera_height(&run.ds)
}

/// The median height (world z) of `ds`'s training cameras; NaN without training frames.
pub fn training_camera_height(ds: &crate::data::Dataset) -> f64 {
    let z: Vec<f64> = ds.split_indices(Split::Train).iter().map(|&f| ds.frames[f].c2w[2][3]).collect();
    if z.is_empty() {
        return f64::NAN;
    }
    crate::util::stats::median(&z)
}

/// The orthographic camera over `grid` looking straight down from world height `top`, in the normalised frame.
fn ortho_view(run: &LoadedRun, grid: &SurveyGrid, top: f64) -> NovelView {
    let s = run.transform.scale;
    let (w, h) = (grid.width as f64, grid.height as f64);
    let centre = [grid.origin[0] + 0.5 * w * grid.gsd, grid.origin[1] - 0.5 * h * grid.gsd, top];
    let pose =
        [[1.0, 0.0, 0.0, centre[0]], [0.0, 1.0, 0.0, centre[1]], [0.0, 0.0, 1.0, centre[2]], [0.0, 0.0, 0.0, 1.0]];
    let f = 1.0 / (grid.gsd * s);
    NovelView {
        name: "survey".into(),
        camera: Camera {
            model: CameraModel::Orthographic,
            fx: f,
            fy: f,
            cx: 0.5 * w,
            cy: 0.5 * h,
            width: grid.width as u32,
            height: grid.height as u32,
            distortion: Distortion::default(),
        },
        c2w: run.transform.pose_to_normalized(&pose),
    }
}

/// Renders `grid` block by block and hands each block to `sink`; `progress` gets the rows done so far.
pub fn render_survey(
    run: &mut LoadedRun,
    grid: &SurveyGrid,
    opts: &SurveyOptions,
    mut sink: impl FnMut(&RowBlock) -> Result<(), SurveyError>,
    mut progress: impl FnMut(usize),
) -> Result<SurveyStats, SurveyError> {
    let t0 = std::time::Instant::now();
    if grid.width > u32::MAX as usize || grid.height > u32::MAX as usize || grid.cells() == 0 {
        return Err(SurveyError::invalid("grid", format!("{} x {} cells", grid.width, grid.height)));
    }
    let top = opts.top.unwrap_or_else(|| median_camera_height(run));
    if !top.is_finite() {
        return Err(SurveyError::invalid("top", format!("{top} is not a height")));
    }
    let view = ortho_view(run, grid, top);
    run.set_novel_views(std::slice::from_ref(&view)).map_err(SurveyError::Render)?;
    let cam = run.novel_camera(0);
    let frames = run.ds.split_indices(Split::Train);
    let nb = run.ds.n_bands();
    let floor = opts.min_accumulation.max(0.5);
    let max_res = run.cfg.field.grid.max_resolution;
    let contraction = run.cfg.sampling.scene_contraction;
    let crop_to_box = opts.scene_box && run.ds.aerial_normalization();
    let rays_per_cell = 1 + opts.consistency.as_ref().map_or(0, |c| c.views);
    let block_rows = (opts.block_rays / (grid.width * rays_per_cell)).clamp(1, grid.height);
    let c2w = view.c2w;
    let mut stats = SurveyStats { cells: grid.cells(), top, ..Default::default() };
    let store = &mut FrameStore::new(opts.image_budget_bytes);
    // The refinement's search line is the DSM's own vertical (world -z), its patch horizontal, and its reference view
    // per cell the most nadir agreeing one (judged from the camera centres) whose image holds the whole sweep.
    let down = (run.transform.rotation() * -glam::DVec3::Z).normalize().to_array();
    let up = down.map(|x| -x);
    let poses = normalised_poses(run);
    let centres: Vec<[f64; 3]> = poses.iter().map(|&(centre, _)| centre).collect();
    let mut row0 = 0;
    while row0 < grid.height {
        let rows = block_rows.min(grid.height - row0);
        let n = rows * grid.width;
        let pixels: Vec<u32> =
            (row0..row0 + rows).flat_map(|r| (0..grid.width).flat_map(move |c| [cam, r as u32, c as u32])).collect();
        let out = run.pipe.render(&pixels).map_err(super::error::NerfError::gpu("the survey rays"))?;
        stats.rays += n;
        let mut height = vec![f32::NAN; n];
        let mut values = vec![f32::NAN; n * nb];
        let mut q = vec![quality::NODATA; n];
        // Cells that pass the accumulation and spread filters: (cell, normalised point, world z).
        let mut kept: Vec<(usize, [f64; 3], f64)> = Vec::new();
        for i in 0..n {
            if out.accumulation[i] < floor || !out.median_depth[i].is_finite() {
                stats.no_surface += 1;
                continue;
            }
            values[i * nb..(i + 1) * nb].copy_from_slice(&out.colour[i * nb..(i + 1) * nb]);
            let (r, c) = ((row0 + i / grid.width) as u32, (i % grid.width) as u32);
            let ray = view.camera.ray_f64(&c2w, r, c);
            let p = [0, 1, 2].map(|k| ray.origin[k] + ray.direction[k] * out.median_depth[i] as f64);
            if crop_to_box && p.iter().any(|v| v.abs() > 1.0) {
                stats.outside_box += 1;
                continue;
            }
            if let Some(max_cells) = opts.max_spread_cells {
                let spread = (out.depth_q75[i] - out.depth_q25[i]) as f64;
                if spread.is_nan() || spread > max_cells * field_cell_size(p, max_res, contraction) {
                    stats.spread += 1;
                    q[i] = quality::GAP;
                    height[i] = run.transform.to_world(p)[2] as f32;
                    continue;
                }
            }
            kept.push((i, p, run.transform.to_world(p)[2]));
        }
        let (agree, agreeing) = match &opts.consistency {
            Some(c) => {
                let points: Vec<([f64; 3], usize)> = kept.iter().map(|&(_, p, _)| (p, usize::MAX)).collect();
                let v = consistency(run, &frames, &points, c).map_err(SurveyError::Render)?;
                stats.rays += v.rays;
                (v.agree.iter().map(|&a| a as usize >= c.min_agree).collect(), v.agreeing)
            }
            None => (vec![true; kept.len()], vec![Vec::new(); kept.len()]),
        };
        // Photometric refinement along the vertical: the most nadir agreeing view is the reference.
        let mut z_of: Vec<Option<f64>> = kept.iter().map(|&(_, _, z)| Some(z)).collect();
        let mut q_of = vec![quality::FIELD_ONLY; kept.len()];
        if let Some(r) = &opts.refine {
            if opts.consistency.is_none() {
                return Err(SurveyError::invalid("photometric refinement", "needs the multi-view consistency check"));
            }
            let nadir = |p: [f64; 3], f: u32| {
                let d = glam::DVec3::from(p) - glam::DVec3::from(centres[f as usize]);
                d.normalize().dot(glam::DVec3::from(down))
            };
            let holds = |p: [f64; 3], f: u32| {
                let (origin, rot) = poses[f as usize];
                holds_sweep(&run.ds.frames[f as usize].camera, origin, &rot, p, down, up, r)
            };
            let (ids, mut pts): (Vec<usize>, Vec<RefinePoint>) = (0..kept.len())
                .filter(|&k| agree[k] && !agreeing[k].is_empty())
                .map(|k| {
                    let p = kept[k].1;
                    let mut partners = agreeing[k].clone();
                    // The most nadir view that holds the whole sweep in its image; the most nadir one if none does.
                    let rank: Vec<(bool, f64)> = partners.iter().map(|&f| (holds(p, f), nadir(p, f))).collect();
                    let best = (0..partners.len())
                        .max_by(|&a, &b| rank[a].0.cmp(&rank[b].0).then(rank[a].1.total_cmp(&rank[b].1)))
                        .unwrap_or(0);
                    let frame = partners.swap_remove(best) as usize;
                    (k, RefinePoint { p, dir: down, frame, partners })
                })
                .unzip();
            // The cross-check: a second sweep from another reference must find the first's height.
            let (res, rs) = refine_points(run, &mut pts, r, store).map_err(SurveyError::Render)?;
            let mut confirmed = vec![true; res.len()];
            if let Some(tolerance) = r.cross_check {
                // From the field's height, where the first sweep started (`pts` holds the moved points).
                let (idx, mut second): (Vec<usize>, Vec<RefinePoint>) = (0..pts.len())
                    .filter(|&i| res[i].supported)
                    .filter_map(|i| {
                        let p = kept[ids[i]].1;
                        cross_check::second_reference(&pts[i], p, &centres, |f| holds(p, f), |f| nadir(p, f))
                            .map(|s| (i, s))
                    })
                    .unzip();
                let (res2, _) = refine_points(run, &mut second, r, store).map_err(SurveyError::Render)?;
                let mut by_cell: Vec<Option<&PointResult>> = vec![None; res.len()];
                for (&i, r2) in idx.iter().zip(&res2) {
                    by_cell[i] = Some(r2);
                }
                for (i, r1) in res.iter().enumerate() {
                    confirmed[i] = !r1.supported || cross_check::confirmed(r1, by_cell[i], tolerance);
                    if !confirmed[i] {
                        stats.unconfirmed += 1;
                    }
                }
            }
            if rs.skipped.is_none() {
                for (((&k, pt), res), &ok) in ids.iter().zip(&pts).zip(&res).zip(&confirmed) {
                    if res.moved && ok {
                        z_of[k] = Some(run.transform.to_world(pt.p)[2]);
                        stats.refined += 1;
                    }
                    if res.supported && ok {
                        q_of[k] = quality::MEASURED;
                    } else {
                        stats.unsupported += 1;
                        if r.drop_unsupported {
                            z_of[k] = None;
                            q_of[k] = quality::GAP;
                        }
                    }
                }
            }
        }
        // A gap keeps the field's height it was turned down with, for `--fill auto`'s check.
        for (((&(i, _, field_z), ok), z), qk) in kept.iter().zip(agree).zip(z_of).zip(q_of) {
            match (ok, z) {
                (false, _) => {
                    stats.inconsistent += 1;
                    q[i] = quality::GAP;
                    height[i] = field_z as f32;
                }
                (true, Some(z)) => {
                    height[i] = z as f32;
                    q[i] = qk;
                    stats.valid += 1;
                }
                (true, None) => {
                    q[i] = quality::GAP;
                    height[i] = field_z as f32;
                }
            }
        }
        sink(&RowBlock { row0, rows, height, values, quality: q })?;
        row0 += rows;
        progress(row0);
    }
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}
