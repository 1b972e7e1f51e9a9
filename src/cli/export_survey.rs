//! `msnerf export dsm RUN --gsd M --out dsm.tif` and `msnerf export ortho RUN --gsd M --out ortho.tif`: the digital
//! surface model and the multispectral true orthomosaic of a trained run, Cloud-Optimized GeoTIFFs on one grid in
//! the dataset's CRS, with PNG previews (see `msnerf::nerf::survey` and `survey_products`). Either command can write
//! the other product from the same rendering (`--ortho`, `--dsm`). RUN may be a `msnerf partition` folder: the
//! blocks' merged products ([`crate::scale::merge_survey`]).

use std::path::PathBuf;

use super::refine_args::RefineArgs;
use super::Cli;
use crate::gpu::Context;
use crate::nerf::export::{Consistency, DEFAULT_MAX_SPREAD_CELLS};
use crate::nerf::refine::RefineOptions;
use crate::nerf::run::LoadedRun;
use crate::nerf::survey::{seen_bounds, DsmFill, SurveyGrid, SurveyOptions, MAX_SURVEY_CELLS};
use crate::nerf::survey_products::{export_survey, SurveyOutputs};
use crate::output::raster::indices::VegetationIndex;
use crate::products::cloud::careful_filters;
use crate::products::survey_grid::{choose_grid, parse_bounds, GridSpec};

#[derive(clap::Args, Debug)]
pub struct SurveyArgs {
    /// Run folder written by `msnerf train`, or a `msnerf partition` folder whose blocks were trained (merged: each
    /// cell rendered by the block that owns it)
    pub run: PathBuf,
    /// Output GeoTIFF (.tif)
    #[arg(long)]
    pub out: PathBuf,
    /// Cell size in world units (metres in a projected CRS)
    #[arg(long, value_parser = super::finite_f64)]
    pub gsd: Option<f64>,
    /// Area in world units: xmin,ymin,xmax,ymax (default: the ground the training cameras saw); snapped outward to
    /// whole cells
    #[arg(long, allow_hyphen_values = true)]
    pub bounds: Option<String>,
    /// Use the grid (origin, cell size, size) of this GeoTIFF instead of --gsd/--bounds, e.g. a LiDAR DSM or an
    /// earlier flight's export, so the rasters align cell for cell
    #[arg(long)]
    pub align_to: Option<PathBuf>,
    /// Refuse grids with more cells than this
    #[arg(long, default_value_t = MAX_SURVEY_CELLS)]
    pub max_cells: usize,
    /// World z the vertical rays start from (default: the training cameras' median height)
    #[arg(long, value_parser = super::finite_f64, allow_hyphen_values = true)]
    pub top: Option<f64>,
    /// Minimum accumulation (opacity) of a cell's ray (at least 0.5)
    #[arg(long, value_parser = super::opacity_f32, default_value_t = SurveyOptions::default().min_accumulation)]
    pub min_accumulation: f32,
    /// DSM: nodata where the ray's weights spread over more than this many finest-grid cells (0: off)
    #[arg(long, value_parser = super::finite_f64, default_value_t = DEFAULT_MAX_SPREAD_CELLS)]
    pub max_spread_cells: f64,
    /// DSM: training views that check each cell's surface point (0: no check; needs --no-refine)
    #[arg(long, default_value_t = Consistency::default().views)]
    pub check_views: usize,
    /// DSM: agreeing views a cell needs
    #[arg(long, default_value_t = Consistency::default().min_agree)]
    pub min_agree: usize,
    /// DSM: largest depth disagreement of a checking view, in its pixel footprints
    #[arg(long, value_parser = super::finite_f64, default_value_t = Consistency::default().tolerance)]
    pub agree_tolerance: f64,
    /// DSM: keep surfaces outside the scene box (the aerial normalisation's unit cube), which are otherwise nodata
    #[arg(long)]
    pub keep_outside_box: bool,
    #[command(flatten)]
    pub refine: RefineArgs,
    /// DSM: cells the images give no photometric support (uniform surfaces such as water, occlusions) and surfaces
    /// the filters turned down: `auto` interpolates the gaps and the unsupported cells whose field height lies within
    /// --fill-tolerance of the interpolation and keeps the field's height where it stands out (crowns); or every
    /// such cell interpolated from the measured cells around it, the field's height, or nodata;
    /// `<stem>_quality.tif` beside the DSM says which each cell is
    #[arg(long, value_enum, default_value_t = DsmFill::default())]
    pub fill: DsmFill,
    /// DSM: how far --fill interpolate reaches, in world units (default: 100 cells)
    #[arg(long, value_parser = super::positive_f64)]
    pub fill_max_distance: Option<f64>,
    /// DSM: how close the field's height must lie to the interpolation for --fill auto to take the interpolation,
    /// in world units
    #[arg(long, value_parser = super::positive_f64, default_value_t = crate::nerf::survey::FILL_TOLERANCE)]
    pub fill_tolerance: f64,
    /// Rays rendered per block (bounds host memory: about 100 bytes per ray)
    #[arg(long, default_value_t = SurveyOptions::default().block_rays)]
    pub block_rays: usize,
    /// RUN is a `msnerf partition` folder: merge the blocks that finished, their cells nodata for the others
    /// (without it, a block that did not finish is an error)
    #[arg(long)]
    pub partial: bool,
}

#[derive(clap::Args, Debug)]
pub struct DsmArgs {
    #[command(flatten)]
    pub common: SurveyArgs,
    /// Also write the true orthomosaic on the same grid from the same rendering
    #[arg(long)]
    pub ortho: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct OrthoArgs {
    #[command(flatten)]
    pub common: SurveyArgs,
    /// Also write the DSM on the same grid from the same rendering
    #[arg(long)]
    pub dsm: Option<PathBuf>,
    /// Vegetation indices written beside the ortho as <stem>_<index>.tif (comma-separated, e.g. ndvi,ndre720)
    #[arg(long, value_delimiter = ',')]
    pub indices: Vec<String>,
}

impl SurveyArgs {
    /// The library options these flags ask for (`dsm`: whether a DSM is written; the refinement and the filters
    /// decide only its heights); errors name the flag.
    pub fn options(&self, dsm: bool) -> anyhow::Result<SurveyOptions> {
        let (max_spread_cells, consistency) =
            careful_filters(self.max_spread_cells, self.check_views, self.min_agree, self.agree_tolerance)?;
        anyhow::ensure!(self.block_rays > 0, "--block-rays must be > 0");
        if let Some(t) = self.top {
            anyhow::ensure!(t.is_finite(), "--top must be a height, got {t}");
        }
        // Unsupported cells keep a height through the refinement; --fill decides what the DSM makes of them.
        let refine = self.refine.options(dsm, consistency.is_some(), self.min_agree, true, RefineOptions::dsm())?;
        Ok(SurveyOptions {
            min_accumulation: self.min_accumulation,
            max_spread_cells,
            scene_box: !self.keep_outside_box,
            top: self.top,
            block_rays: self.block_rays,
            refine,
            consistency,
            fill: self.fill,
            fill_max_distance: self.fill_max_distance,
            fill_tolerance: self.fill_tolerance,
            image_budget_bytes: crate::nerf::export::REFINE_IMAGE_BUDGET,
        })
    }

    /// The grid the flags ask for (`products::survey_grid`); `seen`: what the training cameras saw.
    fn grid(
        &self,
        crs: Option<&crate::geo::Crs>,
        seen: impl FnOnce() -> Result<[f64; 4], crate::products::ProductError>,
    ) -> anyhow::Result<SurveyGrid> {
        let spec = if let Some(p) = &self.align_to {
            anyhow::ensure!(
                self.gsd.is_none() && self.bounds.is_none(),
                "--align-to takes the place of --gsd and --bounds"
            );
            GridSpec::AlignTo(p.clone())
        } else {
            let gsd = self.gsd.ok_or_else(|| anyhow::anyhow!("give --gsd (the cell size) or --align-to"))?;
            GridSpec::Cells { gsd, bounds: self.bounds.as_deref().map(parse_bounds).transpose()? }
        };
        Ok(choose_grid(&spec, self.max_cells, crs, seen)?)
    }
}

/// Renders and writes `outputs`; prints what each filter did and the files.
pub fn run_survey(cli: &Cli, a: &SurveyArgs, mut outputs: SurveyOutputs) -> anyhow::Result<()> {
    let opts = a.options(outputs.dsm.is_some())?;
    // Paths first: a typo in a folder should not wait for a model to load.
    for p in [&outputs.dsm, &outputs.ortho].into_iter().flatten() {
        let dir = p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
        anyhow::ensure!(dir.is_dir(), "{}: the folder {} does not exist", p.display(), dir.display());
    }
    outputs.indices.dedup();
    let ctx = Context::new(&cli.context_desc())?;
    if crate::scale::is_blocks_folder(&a.run) {
        return run_survey_blocks(&ctx, a, &opts, &outputs);
    }
    anyhow::ensure!(!a.partial, "--partial: {} is a run folder, not a `msnerf partition` folder", a.run.display());
    let mut run = LoadedRun::load(&ctx, &a.run)?;
    let crs = run.ds.crs.clone();
    let grid = a.grid(crs.as_ref(), || Ok(seen_bounds(&mut run)?))?;
    let bar = indicatif::ProgressBar::new(grid.height as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("rendering {bar:30} {pos}/{len} rows, ETA {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let report = export_survey(&mut run, &grid, &opts, &outputs, |rows| bar.set_position(rows as u64))?;
    bar.finish_and_clear();
    let s = &report.stats;
    let b = grid.bounds();
    println!(
        "grid {} x {} cells of {} over {:.3},{:.3},{:.3},{:.3}; vertical rays from z = {:.3}",
        grid.width, grid.height, grid.gsd, b[0], b[1], b[2], b[3], s.top
    );
    println!(
        "{} cells: {} with a height, {} without a surface, {} outside the scene box, {} with spread weights, {} \
         inconsistent across views, {} refined photometrically, {} without photometric support ({} of them not \
         confirmed by a second reference); {} rays in {:.1} s",
        s.cells,
        s.valid,
        s.no_surface,
        s.outside_box,
        s.spread,
        s.inconsistent,
        s.refined,
        s.unsupported,
        s.unconfirmed,
        s.rays,
        s.seconds
    );
    if s.measured + s.interpolated + s.field_only > 0 {
        println!("{}", s.quality_line());
    }
    for n in &report.notes {
        println!("note: {n}");
    }
    if let Some(b) = crate::util::mem::peak_rss_bytes() {
        println!("peak host memory {:.0} MiB", b as f64 / 1048576.0);
    }
    let crs = run
        .ds
        .crs
        .as_ref()
        .map_or("the dataset's local frame: no crs".to_string(), |c| format!("crs {}", c.describe()));
    for f in &report.files {
        println!("-> {} ({crs})", f.display());
    }
    Ok(())
}

/// `export dsm|ortho BLOCKS`: the merged products of block-wise training ([`crate::scale::merge_survey`]); the
/// default area is the blocks' cores.
fn run_survey_blocks(
    ctx: &Context,
    a: &SurveyArgs,
    opts: &SurveyOptions,
    outputs: &SurveyOutputs,
) -> anyhow::Result<()> {
    use crate::scale::merge_survey::{cores_bounds, flight_top, merge_survey};
    let blocks = crate::scale::runner::read_blocks(&a.run)?;
    let ds = crate::data::load_dataset(&blocks.source, &crate::data::LoadOptions::default())?;
    let crs = ds.crs.clone();
    let grid = a.grid(crs.as_ref(), || Ok(cores_bounds(&blocks)))?;
    let opts = &SurveyOptions { top: Some(opts.top.map_or_else(|| flight_top(&blocks, &ds), Ok)?), ..opts.clone() };
    let bar = indicatif::ProgressBar::new(grid.height as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} rows, ETA {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let merged = merge_survey(ctx, &a.run, &blocks, &grid, opts, outputs, a.partial, |name, rows, of| {
        bar.set_message(name.to_string());
        bar.set_length(of as u64);
        bar.set_position(rows as u64);
    })?;
    bar.finish_and_clear();
    let s = &merged.report.stats;
    let b = grid.bounds();
    println!(
        "grid {} x {} cells of {} over {:.3},{:.3},{:.3},{:.3}; vertical rays from z = {:.3}",
        grid.width, grid.height, grid.gsd, b[0], b[1], b[2], b[3], s.top
    );
    for p in &merged.blocks {
        let t = &p.stats;
        println!(
            "{}: owns {} cells, {} with a value; its rectangle: {} without a surface, {} outside its scene box, {} \
             with spread weights, {} inconsistent across views; {} rays in {:.1} s",
            p.block, p.owned, p.valid, t.no_surface, t.outside_box, t.spread, t.inconsistent, t.rays, t.seconds
        );
    }
    for m in &merged.missing {
        println!("left out (not trained or not finished; its cells are nodata): {m}");
    }
    println!("{} cells: {} with a value; {} rays in {:.1} s", s.cells, s.valid, s.rays, s.seconds);
    for n in &merged.report.notes {
        println!("note: {n}");
    }
    let crs = crs.as_ref().map_or("the dataset's local frame: no crs".to_string(), |c| format!("crs {}", c.describe()));
    for f in &merged.report.files {
        println!("-> {} ({crs})", f.display());
    }
    Ok(())
}

pub fn run_dsm(cli: &Cli, a: &DsmArgs) -> anyhow::Result<()> {
    run_survey(
        cli,
        &a.common,
        SurveyOutputs { dsm: Some(a.common.out.clone()), ortho: a.ortho.clone(), indices: vec![] },
    )
}

pub fn run_ortho(cli: &Cli, a: &OrthoArgs) -> anyhow::Result<()> {
    let indices = a.indices.iter().map(|s| VegetationIndex::parse(s)).collect::<Result<Vec<_>, _>>()?;
    run_survey(cli, &a.common, SurveyOutputs { dsm: a.dsm.clone(), ortho: Some(a.common.out.clone()), indices })
}
