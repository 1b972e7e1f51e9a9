//! `msnerf export pointcloud RUN --out cloud.ply|cloud.las`: a multispectral point cloud in the dataset's own world
//! frame and units (see `msnerf::nerf::export`), with statistical outlier removal, an optional crop box and a target
//! point count. PLY carries every band as float and a display RGB; LAS 1.4 point format 8 carries RGB + NIR and the
//! other bands as Extra Bytes. `--normals` adds each point's surface normal from the density field (PLY `nx ny nz`,
//! LAS Extra Bytes `NormalX/Y/Z`). By default the export is the careful one of `msnerf::nerf::export` (exact median
//! crossing, spread filter, multi-view consistency, confidence scalar fields, optional `--gsd` thinning); `--legacy`
//! is the accumulation-threshold export that came before it. `export dsm` and `export ortho` are in
//! [`super::export_survey`].

use super::refine_args::RefineArgs;
use super::Cli;
use crate::geo::Crs;
use crate::gpu::Context;
use crate::nerf::export::{export_points_with_stats, Consistency, ExportOptions, ExportStats};
use crate::nerf::run::LoadedRun;
use crate::output::pointcloud::{self, LasOptions, PlyOptions, PointCloud};
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
}

#[derive(clap::Args, Debug, Clone)]
pub struct PointcloudArgs {
    /// Run folder written by `msnerf train`, or a `msnerf partition` folder whose blocks were trained (merged)
    pub run: PathBuf,
    /// Output file: .ply or .las
    #[arg(long)]
    pub out: PathBuf,
    /// Training rays to render before filtering
    #[arg(long, default_value_t = 200_000)]
    pub rays: usize,
    /// Keep rays whose accumulation (opacity) is at least this
    #[arg(long, value_parser = super::opacity_f32, default_value_t = 0.5)]
    pub min_accumulation: f32,
    /// Statistical outlier removal: neighbours and standard-deviation ratio (0 neighbours turns it off)
    #[arg(long, default_value_t = 20)]
    pub outlier_neighbours: usize,
    #[arg(long, value_parser = super::finite_f64, default_value_t = 10.0)]
    pub outlier_std_ratio: f64,
    /// Axis-aligned crop box in world units: minx,miny,minz,maxx,maxy,maxz
    #[arg(long, value_delimiter = ',', num_args = 6)]
    pub crop: Option<Vec<f64>>,
    /// At most this many points (random, seeded subsample)
    #[arg(long)]
    pub points: Option<usize>,
    #[arg(long, default_value_t = 42)]
    pub seed: u64,
    /// Also write surface normals: -grad(density) of the NeRF field at each point, facing the camera that saw it
    #[arg(long)]
    pub normals: bool,
    /// Drop rays whose weights' interquartile depth spread exceeds this many cells of the field's finest grid level
    /// (0 turns the filter off)
    #[arg(long, value_parser = super::finite_f64, default_value_t = 8.0)]
    pub max_spread_cells: f64,
    /// Multi-view consistency: other training views checked per point (0 turns the check off; needs --no-refine,
    /// since the refinement correlates against the agreeing views)
    #[arg(long, default_value_t = 6)]
    pub check_views: usize,
    /// Multi-view consistency: agreeing views a point needs
    #[arg(long, default_value_t = 2)]
    pub min_agree: usize,
    /// Multi-view consistency: largest depth disagreement, in pixel footprints of the checking view
    #[arg(long, value_parser = super::finite_f64, default_value_t = 2.0)]
    pub agree_tolerance: f64,
    /// Thin to one point per cube of this edge (world units, e.g. metres): the most consistent, then the least
    /// spread point of each cell
    #[arg(long, value_parser = super::finite_f64)]
    pub gsd: Option<f64>,
    /// The export before issue 18 (accumulation threshold only): no spread filter, no consistency check, no
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
            anyhow::ensure!(
                b.len() == 6 && b.iter().all(|v| v.is_finite()) && (0..3).all(|k| b[k] < b[k + 3]),
                "--crop needs minx,miny,minz,maxx,maxy,maxz with each min below its max, got {b:?}"
            );
        }
        let (max_spread_cells, consistency) =
            careful_filters(self.max_spread_cells, self.check_views, self.min_agree, self.agree_tolerance)?;
        if let Some(g) = self.gsd {
            anyhow::ensure!(g.is_finite() && g > 0.0, "--gsd must be > 0, got {g}");
        }
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
            refine: self.refine.options(true, consistency.is_some(), self.min_agree, self.keep_unsupported)?,
            consistency,
        })
    }
}

/// The careful export's spread and consistency filters from their flags (`export pointcloud`, `dsm` and `ortho`
/// share them): 0 turns a filter off; errors name the flag.
pub fn careful_filters(
    max_spread_cells: f64,
    check_views: usize,
    min_agree: usize,
    agree_tolerance: f64,
) -> anyhow::Result<(Option<f64>, Option<Consistency>)> {
    anyhow::ensure!(
        max_spread_cells.is_finite() && max_spread_cells >= 0.0,
        "--max-spread-cells must be >= 0, got {max_spread_cells}"
    );
    anyhow::ensure!(
        agree_tolerance.is_finite() && agree_tolerance > 0.0,
        "--agree-tolerance must be > 0, got {agree_tolerance}"
    );
    anyhow::ensure!(
        check_views == 0 || (1..=check_views).contains(&min_agree),
        "--min-agree must be between 1 and --check-views ({check_views}), got {min_agree}"
    );
    Ok((
        (max_spread_cells > 0.0).then_some(max_spread_cells),
        (check_views > 0).then_some(Consistency { views: check_views, min_agree, tolerance: agree_tolerance }),
    ))
}

/// Filters a cloud as the flags ask.
pub fn filter(mut cloud: PointCloud, a: &PointcloudArgs) -> anyhow::Result<PointCloud> {
    if let Some(b) = &a.crop {
        let inside = |p: &[f64; 3]| (0..3).all(|k| p[k] >= b[k] && p[k] <= b[k + 3]);
        cloud = pointcloud::filter::crop(&cloud, inside)?.0;
    }
    if a.outlier_neighbours > 0 && cloud.len() > a.outlier_neighbours {
        cloud = pointcloud::filter::remove_statistical_outliers(&cloud, a.outlier_neighbours, a.outlier_std_ratio)?.0;
    }
    if let Some(g) = a.gsd {
        cloud = pointcloud::thin::thin_to_grid(&cloud, g, &["agreeing_views"], &["depth_spread"])?.0;
    }
    if let Some(n) = a.points {
        cloud = pointcloud::filter::subsample(&cloud, n, a.seed)?.0;
    }
    Ok(cloud)
}

/// Writes `cloud` as PLY or LAS (by extension), carrying the dataset's `crs`: LAS as its OGC WKT record
/// (`LASF_Projection`/2112), PLY as `comment crs EPSG:n` and `comment crs_wkt WKT` lines.
pub fn write_cloud(cloud: &PointCloud, out: &std::path::Path, crs: Option<&Crs>) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("ply") => {
            let comments =
                crs.map(|c| vec![format!("crs {}", c.key()), format!("crs_wkt {}", c.wkt)]).unwrap_or_default();
            pointcloud::write_ply(out, cloud, &PlyOptions { comments, ..Default::default() })?
        }
        Some("las") => {
            pointcloud::write_las(out, cloud, &LasOptions { wkt: crs.map(|c| c.wkt.clone()), ..Default::default() })?
        }
        _ => anyhow::bail!("--out {}: the file must end in .ply or .las", out.display()),
    }
    Ok(())
}

pub fn run(cli: &Cli, a: &ExportArgs) -> anyhow::Result<()> {
    let a = match &a.what {
        ExportWhat::Pointcloud(a) => a,
        ExportWhat::Dsm(a) => return super::export_survey::run_dsm(cli, a),
        ExportWhat::Ortho(a) => return super::export_survey::run_ortho(cli, a),
    };
    let ext_ok = matches!(a.out.extension().and_then(|e| e.to_str()), Some("ply" | "las" | "PLY" | "LAS"));
    anyhow::ensure!(ext_ok, "--out {}: the file must end in .ply or .las", a.out.display());
    let opts = a.export_options()?;
    let ctx = Context::new(&cli.context_desc())?;
    if a.run.join("blocks.json").is_file() {
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

/// One line per filter: what it removed.
pub fn summary(s: &ExportStats, min_accumulation: f32, written: usize) -> String {
    format!(
        "{} rays rendered: {} below accumulation {min_accumulation}, {} outside the scene box, {} with spread weights, \
         {} inconsistent across views ({} check rays); {} points kept, {} written after outlier removal and thinning",
        s.rays,
        s.below_accumulation,
        s.outside_box,
        s.spread,
        s.inconsistent,
        s.check_rays,
        s.kept,
        written
    ) + &refine_summary(s)
}

/// A note when the refinement dropped most of the consistent points: the images carry little texture (uniform
/// materials), and the user should know the flags that keep them.
pub fn unsupported_note(s: &ExportStats) -> Option<String> {
    let points = s.refine.as_ref().map_or(0, |r| r.points);
    (points > 0 && 2 * s.unsupported > points).then(|| {
        format!(
            "note: {} of {points} consistent points ({:.0} %) had no photometric support and were dropped: the \
             training images carry little texture there (uniform surfaces), or the surface lies beyond \
             --refine-range; --keep-unsupported keeps them where the field put them, --no-refine skips the refinement",
            s.unsupported,
            100.0 * s.unsupported as f64 / points as f64
        )
    })
}

/// The refinement's line of the summary (empty when it was off).
fn refine_summary(s: &ExportStats) -> String {
    match &s.refine {
        None => String::new(),
        Some(r) => match &r.skipped {
            Some(why) => format!("; photometric refinement skipped: {why}"),
            None => format!(
                "; photometric refinement moved {} of {} points (median |shift| {:.3} in world units), kept {} where \
                 the field put them (weak correlation), {} without photometric support {}",
                r.moved,
                r.points,
                r.median_shift,
                r.kept,
                r.points - r.moved - r.kept,
                if s.unsupported > 0 { "dropped" } else { "kept" }
            ),
        },
    }
}
