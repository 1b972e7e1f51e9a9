//! `msnerf export dtm --dsm DSM.tif --out dtm.tif`, `msnerf export chm --dsm DSM.tif --dtm DTM.tif --out chm.tif`
//! and `msnerf export trees --chm CHM.tif [--dtm DTM.tif] [--ortho ORTHO.tif] --out trees.geojson`: bare earth by
//! SMRF, the canopy height model and the trees, from rasters on one grid (any DSM in a projected CRS: `export dsm`'s,
//! OpenDroneMap's, a LiDAR one). The work is `msnerf::products::canopy`; no GPU is needed.

use std::path::PathBuf;

use crate::products::canopy::{make_chm, make_dtm, make_trees};
use crate::products::terrain::SmrfParams;
use crate::products::trees::{CrownParams, TopParams};

#[derive(clap::Args, Debug)]
pub struct DtmArgs {
    /// The DSM (GeoTIFF; `<stem>_quality.tif` beside it, as `export dsm` writes, restricts ground to measured and
    /// interpolated cells)
    #[arg(long)]
    pub dsm: PathBuf,
    /// Output GeoTIFF (.tif); `<stem>_quality.tif` says which cells are ground and which interpolated
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub smrf: SmrfArgs,
    /// Take every DSM cell as a ground candidate, the field-only heights of a DSM's quality raster included
    #[arg(long)]
    pub use_field_heights: bool,
}

/// SMRF's parameters (PDAL `filters.smrf`'s names and defaults).
#[derive(clap::Args, Debug, Clone)]
pub struct SmrfArgs {
    /// SMRF cell size, world units (a whole number of DSM cells)
    #[arg(long = "smrf-cell", value_parser = super::positive_f64, default_value_t = SmrfParams::default().cell)]
    pub cell: f64,
    /// Slope tolerance of the morphological opening (rise over run)
    #[arg(long = "smrf-slope", value_parser = super::positive_f64, default_value_t = SmrfParams::default().slope)]
    pub slope: f64,
    /// Largest window radius, world units: objects wider than twice this stay ground
    #[arg(long = "smrf-window", value_parser = super::positive_f64, default_value_t = SmrfParams::default().window)]
    pub window: f64,
    /// Elevation threshold of the final ground test, world units
    #[arg(long = "smrf-threshold", value_parser = super::finite_f64, default_value_t = SmrfParams::default().threshold)]
    pub threshold: f64,
    /// Scale of the terrain slope added to the threshold
    #[arg(long = "smrf-scalar", value_parser = super::finite_f64, default_value_t = SmrfParams::default().scalar)]
    pub scalar: f64,
}

impl SmrfArgs {
    pub fn params(&self) -> SmrfParams {
        SmrfParams {
            cell: self.cell,
            slope: self.slope,
            window: self.window,
            threshold: self.threshold,
            scalar: self.scalar,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct ChmArgs {
    /// The DSM (GeoTIFF)
    #[arg(long)]
    pub dsm: PathBuf,
    /// The DTM on the DSM's grid (GeoTIFF, e.g. from `export dtm`)
    #[arg(long)]
    pub dtm: PathBuf,
    /// Output GeoTIFF (.tif)
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct TreesArgs {
    /// The canopy height model (GeoTIFF, e.g. from `export chm`)
    #[arg(long)]
    pub chm: PathBuf,
    /// The DTM on the CHM's grid: each tree's ground height
    #[arg(long)]
    pub dtm: Option<PathBuf>,
    /// The orthomosaic on the CHM's grid: band means and NDVI per crown; crowns below NDVI 0.3 (roofs) are set apart
    #[arg(long)]
    pub ortho: Option<PathBuf>,
    /// Output GeoJSON (.geojson); `<stem>.csv` and `<stem>_crowns.tif` are written beside it
    #[arg(long)]
    pub out: PathBuf,
    /// Lowest tree, world units above the terrain
    #[arg(long, value_parser = super::positive_f64, default_value_t = TopParams::default().min_height)]
    pub min_height: f64,
    /// Largest crown diameter, world units
    #[arg(long, value_parser = super::positive_f64, default_value_t = CrownParams::default().max_diameter)]
    pub max_crown: f64,
    /// Share of a crown the DSM must have measured or interpolated (read from `<chm stem>_quality.tif`, which
    /// `export chm` copies from the DSM's), 0 to 1
    #[arg(long, value_parser = super::unit_f64, default_value_t = CrownParams::default().min_support)]
    pub min_support: f64,
    /// Fewest training images that saw a tree's top (read from `<chm stem>_views.tif`, which `export chm` copies
    /// from the DSM's)
    #[arg(long, default_value_t = TopParams::default().min_views)]
    pub min_views: usize,
    /// Smallest crown, as a share of the disc of the crown width expected at the top's height, 0 to 1
    #[arg(long, value_parser = super::unit_f64, default_value_t = CrownParams::default().min_area_fraction)]
    pub min_crown_fraction: f64,
}

fn ensure_ext(path: &std::path::Path, exts: &[&str], flag: &str) -> anyhow::Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    anyhow::ensure!(
        ext.as_deref().is_some_and(|e| exts.contains(&e)),
        "{flag} {}: the file must end in .{}",
        path.display(),
        exts.join(" or .")
    );
    Ok(())
}

pub fn run_dtm(a: &DtmArgs) -> anyhow::Result<()> {
    ensure_ext(&a.out, &["tif", "tiff"], "--out")?;
    crate::util::atomic::check_not_an_input(&a.out, &[("--dsm", a.dsm.as_path())])?;
    let s = make_dtm(&a.dsm, &a.out, &a.smrf.params(), a.use_field_heights)?;
    println!("{}", s.line());
    s.files.iter().for_each(|f| println!("-> {}", f.display()));
    Ok(())
}

pub fn run_chm(a: &ChmArgs) -> anyhow::Result<()> {
    ensure_ext(&a.out, &["tif", "tiff"], "--out")?;
    crate::util::atomic::check_not_an_input(&a.out, &[("--dsm", a.dsm.as_path()), ("--dtm", a.dtm.as_path())])?;
    let s = make_chm(&a.dsm, &a.dtm, &a.out)?;
    println!("{}", s.line());
    s.files.iter().for_each(|f| println!("-> {}", f.display()));
    Ok(())
}

pub fn run_trees(a: &TreesArgs) -> anyhow::Result<()> {
    ensure_ext(&a.out, &["geojson", "json"], "--out")?;
    let mut inputs = vec![("--chm", a.chm.as_path())];
    inputs.extend(a.dtm.as_deref().map(|p| ("--dtm", p)));
    inputs.extend(a.ortho.as_deref().map(|p| ("--ortho", p)));
    crate::util::atomic::check_not_an_input(&a.out, &inputs)?;
    let tops = TopParams { min_height: a.min_height, min_views: a.min_views, ..TopParams::default() };
    let crowns = CrownParams {
        min_height: a.min_height,
        max_diameter: a.max_crown,
        min_support: a.min_support,
        min_area_fraction: a.min_crown_fraction,
        ..CrownParams::default()
    };
    let s = make_trees(&a.chm, a.dtm.as_deref(), a.ortho.as_deref(), &a.out, &tops, &crowns)?;
    s.notes.iter().for_each(|n| println!("note: {n}"));
    println!("{}", s.line());
    s.files.iter().for_each(|f| println!("-> {}", f.display()));
    Ok(())
}
