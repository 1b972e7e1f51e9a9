//! `msnerf export pointcloud RUN --out cloud.ply|cloud.las`: a multispectral point cloud in the dataset's own world
//! frame and units (see `msnerf::nerf::export`), with statistical outlier removal, an optional crop box and a target
//! point count. PLY carries every band as float and a display RGB; LAS 1.4 point format 8 carries RGB + NIR and the
//! other bands as Extra Bytes. `--normals` adds each point's surface normal from the density field (PLY `nx ny nz`,
//! LAS Extra Bytes `NormalX/Y/Z`). By default the export is the careful one of `msnerf::nerf::export` (exact median
//! crossing, spread filter, multi-view consistency, confidence scalar fields, optional `--gsd` thinning); `--legacy`
//! is the accumulation-threshold export that came before it. `export dsm` and `export ortho` are in
//! [`super::export_survey`]; `export dtm`, `chm` and `trees` in [`super::export_canopy`].

use super::refine_args::RefineArgs;
use super::Cli;
use crate::gpu::Context;
use crate::nerf::export::{export_points_with_stats, Consistency, ExportOptions, DEFAULT_MAX_SPREAD_CELLS};
use crate::nerf::run::LoadedRun;
use crate::output::pointcloud::{self, PointCloud};
use crate::products::cloud::{careful_filters, summary, unsupported_note, write_cloud, CloudFilter};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    #[command(subcommand)]
    pub what: ExportWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum ExportWhat {
    /// Multispectral point cloud (.ply or .las)
    Pointcloud(PointcloudArgs),
    /// Digital surface model: first-surface heights on a grid, a Cloud-Optimized GeoTIFF in the dataset's CRS
    Dsm(super::export_survey::DsmArgs),
    /// Multispectral true orthomosaic: every band seen straight down, a Cloud-Optimized GeoTIFF on the DSM's grid
    Ortho(super::export_survey::OrthoArgs),
    /// Digital terrain model (bare earth) from a DSM by SMRF ground filtering, on the DSM's grid
    Dtm(super::export_canopy::DtmArgs),
    /// Canopy height model (DSM - DTM) on their grid
    Chm(super::export_canopy::ChmArgs),
    /// Tree tops, crowns, heights and per-crown band means and NDVI from a CHM (GeoJSON and CSV)
    Trees(super::export_canopy::TreesArgs),
}

#[derive(clap::Args, Debug, Clone)]
pub struct PointcloudArgs {
    /// Run folder written by `msnerf train`, or a `msnerf partition` folder whose blocks were trained (merged)
    pub run: PathBuf,
    /// Output file: .ply or .las
    #[arg(long)]
    pub out: PathBuf,
    /// Training rays to render before filtering
    #[arg(long, default_value_t = ExportOptions::default().rays)]
    pub rays: usize,
    /// Keep rays whose accumulation (opacity) is at least this
    #[arg(long, value_parser = super::opacity_f32, default_value_t = ExportOptions::default().min_accumulation)]
    pub min_accumulation: f32,
    /// Statistical outlier removal: neighbours and standard-deviation ratio (0 neighbours turns it off)
    #[arg(long, default_value_t = CloudFilter::default().outlier_neighbours)]
    pub outlier_neighbours: usize,
    #[arg(long, value_parser = super::finite_f64, default_value_t = CloudFilter::default().outlier_std_ratio)]
    pub outlier_std_ratio: f64,
    /// Axis-aligned crop box in world units: minx,miny,minz,maxx,maxy,maxz
    #[arg(long, value_delimiter = ',', num_args = 6)]
    pub crop: Option<Vec<f64>>,
    /// At most this many points (random, seeded subsample)
    #[arg(long)]
    pub points: Option<usize>,
    #[arg(long, default_value_t = ExportOptions::default().seed)]
    pub seed: u64,
    /// Also write surface normals: -grad(density) of the NeRF field at each point, facing the camera that saw it
    #[arg(long)]
    pub normals: bool,
    /// Drop rays whose weights' interquartile depth spread exceeds this many cells of the field's finest grid level
    /// (0 turns the filter off)
    #[arg(long, value_parser = super::finite_f64, default_value_t = DEFAULT_MAX_SPREAD_CELLS)]
    pub max_spread_cells: f64,
    /// Multi-view consistency: other training views checked per point (0 turns the check off; needs --no-refine,
    /// since the refinement correlates against the agreeing views)
    #[arg(long, default_value_t = Consistency::default().views)]
    pub check_views: usize,
    /// Multi-view consistency: agreeing views a point needs
    #[arg(long, default_value_t = Consistency::default().min_agree)]
    pub min_agree: usize,
    /// Multi-view consistency: largest depth disagreement, in pixel footprints of the checking view
    #[arg(long, value_parser = super::finite_f64, default_value_t = Consistency::default().tolerance)]
    pub agree_tolerance: f64,
    /// Thin to one point per cube of this edge (world units, e.g. metres): the most consistent, then the least
    /// spread point of each cell
    #[arg(long, value_parser = super::finite_f64)]
    pub gsd: Option<f64>,
    /// The earlier export (accumulation threshold only): no spread filter, no consistency check, no
    /// scene-box crop
    #[arg(long)]
    pub legacy: bool,
    /// Keep points outside the scene box (the aerial normalisation's unit cube: the ground footprint, half its
    /// half-size below the ground and 1.5 times above), which the export otherwise drops as nerfstudio's does
    #[arg(long)]
    pub keep_outside_box: bool,
    #[command(flatten)]
    pub refine: RefineArgs,
    /// Photometric refinement: keep the points the images do not support (uniform surfaces, occlusions) where the
    /// field put them, instead of dropping them
    #[arg(long)]
    pub keep_unsupported: bool,
    /// RUN is a `msnerf partition` folder: merge the blocks that finished and list the others (without it, a block
    /// that is not trained is an error)
    #[arg(long)]
    pub partial: bool,
}

/// Largest `--rays`: each ray keeps about 100 bytes until filtering, so 2^28 rays need some 27 GB.
pub const MAX_EXPORT_RAYS: usize = 1 << 28;

impl PointcloudArgs {
    /// The library options these flags ask for; errors name the flag.
    pub fn export_options(&self) -> anyhow::Result<ExportOptions> {
        anyhow::ensure!(
            self.rays > 0 && self.rays <= MAX_EXPORT_RAYS,
            "--rays must be 1..={MAX_EXPORT_RAYS}, got {}",
            self.rays
        );
        if let Some(b) = &self.crop {
            anyhow::ensure!(b.len() == 6, "--crop needs minx,miny,minz,maxx,maxy,maxz, got {b:?}");
        }
        let (max_spread_cells, consistency) =
            careful_filters(self.max_spread_cells, self.check_views, self.min_agree, self.agree_tolerance)?;
        self.cloud_filter().validate()?;
        if self.legacy {
            return Ok(ExportOptions {
                normals: self.normals,
                ..ExportOptions::legacy(self.rays, self.min_accumulation, self.seed)
            });
        }
        Ok(ExportOptions {
            rays: self.rays,
            min_accumulation: self.min_accumulation,
            seed: self.seed,
            normals: self.normals,
            max_spread_cells,
            scene_box: !self.keep_outside_box,
            refine: self.refine.options(
                true,
                consistency.is_some(),
                self.min_agree,
                self.keep_unsupported,
                crate::nerf::refine::RefineOptions::default(),
            )?,
            consistency,
            image_budget_bytes: crate::nerf::export::REFINE_IMAGE_BUDGET,
        })
    }
}

impl PointcloudArgs {
    /// The post-filters these flags ask for.
    pub fn cloud_filter(&self) -> CloudFilter {
        CloudFilter {
            crop: self.crop.as_ref().map(|b| std::array::from_fn(|k| b[k])),
            outlier_neighbours: self.outlier_neighbours,
            outlier_std_ratio: self.outlier_std_ratio,
            gsd: self.gsd,
            points: self.points,
            seed: self.seed,
        }
    }
}

/// Filters a cloud as the flags ask.
pub fn filter(cloud: PointCloud, a: &PointcloudArgs) -> anyhow::Result<PointCloud> {
    Ok(a.cloud_filter().apply(cloud)?)
}

pub fn run(cli: &Cli, a: &ExportArgs) -> anyhow::Result<()> {
    let a = match &a.what {
        ExportWhat::Pointcloud(a) => a,
        ExportWhat::Dsm(a) => return super::export_survey::run_dsm(cli, a),
        ExportWhat::Ortho(a) => return super::export_survey::run_ortho(cli, a),
        ExportWhat::Dtm(a) => return super::export_canopy::run_dtm(a),
        ExportWhat::Chm(a) => return super::export_canopy::run_chm(a),
        ExportWhat::Trees(a) => return super::export_canopy::run_trees(a),
    };
    let ext_ok = matches!(a.out.extension().and_then(|e| e.to_str()), Some("ply" | "las" | "PLY" | "LAS"));
    anyhow::ensure!(ext_ok, "--out {}: the file must end in .ply or .las", a.out.display());
    let opts = a.export_options()?;
    let ctx = Context::new(&cli.context_desc())?;
    if crate::scale::is_blocks_folder(&a.run) {
        return export_blocks(&ctx, a, &opts);
    }
    let mut run = LoadedRun::load(&ctx, &a.run)?;
    let (raw, stats) = export_points_with_stats(&mut run, &opts)?;
    let cloud = filter(raw, a)?;
    write_cloud(&cloud, &a.out, run.ds.crs.as_ref())?;
    println!("{}", summary(&stats, a.min_accumulation, cloud.len()));
    if let Some(note) = unsupported_note(&stats) {
        println!("{note}");
    }
    match &run.ds.crs {
        Some(c) => println!("-> {} (crs {})", a.out.display(), c.describe()),
        None => println!("-> {} (the dataset's local frame: no crs)", a.out.display()),
    }
    Ok(())
}

/// `export pointcloud BLOCKS`: every block's cloud, filtered as the flags ask (the point budget applied to the
/// merged cloud), cut to the block's core and joined ([`crate::scale::merge`]).
fn export_blocks(ctx: &Context, a: &PointcloudArgs, opts: &ExportOptions) -> anyhow::Result<()> {
    let blocks = crate::scale::runner::read_blocks(&a.run)?;
    let mut crs = None;
    let per_block = PointcloudArgs { points: None, ..a.clone() };
    let (merged, stats) = crate::scale::merge::merge_clouds(&a.run, &blocks, a.partial, |b, run| {
        let fail = |e: &dyn std::fmt::Display| crate::scale::ScaleError::Block {
            block: b.name.clone(),
            reason: e.to_string(),
        };
        let mut r = LoadedRun::load(ctx, run).map_err(|e| fail(&e))?;
        let (raw, _) = export_points_with_stats(&mut r, opts).map_err(|e| fail(&e))?;
        crs = r.ds.crs.clone();
        filter(raw, &per_block).map_err(|e| fail(&e))
    })?;
    let cloud = match a.points {
        Some(n) => pointcloud::filter::subsample(&merged, n, a.seed)?.0,
        None => merged,
    };
    write_cloud(&cloud, &a.out, crs.as_ref())?;
    for (name, exported, kept) in &stats.blocks {
        println!("{name}: {kept} of its {exported} points lie in its core");
    }
    for m in &stats.missing {
        println!("left out (not trained or not finished): {m}");
    }
    println!("-> {} ({} points from {} blocks)", a.out.display(), cloud.len(), stats.blocks.len());
    Ok(())
}
