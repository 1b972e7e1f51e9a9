//! `msnerf compare-raster --pred dsm.tif --ref reference.tif [--classes classes.tif] [--within LIST] [--peak P]
//! [--json]`: a DSM or orthomosaic against a reference raster in the same CRS (a LiDAR DSM, the simulator's truth),
//! per band and per class of interior cells (see `msnerf::output::compare_raster`). Needs no GPU.

use std::path::PathBuf;

use crate::output::compare::parse_within;
use crate::output::compare_raster::{compare_rasters, QualityLayer, RasterCompareOptions};
use crate::output::raster::geotiff_read::read_geotiff;

#[derive(clap::Args, Debug)]
pub struct CompareRasterArgs {
    /// The raster to evaluate (GeoTIFF)
    #[arg(long)]
    pub pred: PathBuf,
    /// The reference raster (GeoTIFF, same CRS and band count; any north-up grid)
    #[arg(long = "ref")]
    pub reference: PathBuf,
    /// A class raster (integer codes; band named `classes 1=ground 2=roof ...`) for per-class statistics over
    /// interior cells
    #[arg(long)]
    pub classes: Option<PathBuf>,
    /// The prediction's quality raster (a DSM's `<stem>_quality.tif`) for statistics per code over every cell:
    /// measured, interpolated, field only
    #[arg(long)]
    pub quality: Option<PathBuf>,
    /// Tolerances (raster units, comma-separated) for the fractions of cells within each
    #[arg(long, default_value = "0.1,0.25,0.5,1.0")]
    pub within: String,
    /// Peak value for PSNR (1 for reflectance); no PSNR without it
    #[arg(long, value_parser = super::finite_f64)]
    pub peak: Option<f64>,
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report to this file
    #[arg(long)]
    pub output: Option<PathBuf>,
}

pub fn run(args: &CompareRasterArgs) -> anyhow::Result<()> {
    let within = parse_within(&args.within)?;
    if let Some(p) = args.peak {
        anyhow::ensure!(p.is_finite() && p > 0.0, "--peak must be > 0, got {p}");
    }
    if let Some(out) = &args.output {
        let mut inputs = vec![("--pred", args.pred.as_path()), ("--ref", args.reference.as_path())];
        inputs.extend(args.classes.as_deref().map(|c| ("--classes", c)));
        inputs.extend(args.quality.as_deref().map(|c| ("--quality", c)));
        crate::util::atomic::check_not_an_input(out, &inputs)?;
    }
    let pred = read_geotiff(&args.pred)?;
    let reference = read_geotiff(&args.reference)?;
    let classes = args.classes.as_ref().map(|c| read_geotiff(c)).transpose()?;
    let quality_raster = args.quality.as_ref().map(|c| read_geotiff(c)).transpose()?;
    let quality = quality_raster.as_ref().map(|raster| QualityLayer {
        raster,
        names: crate::nerf::survey::quality::NAMES.iter().map(|&(c, n)| (i64::from(c), n.to_string())).collect(),
    });
    let opts = RasterCompareOptions { within, peak: args.peak };
    let report = compare_rasters(&pred, &reference, classes.as_ref(), quality.as_ref(), &opts)?;
    let json = report.to_json();
    if let Some(out) = &args.output {
        crate::output::atomic::write_bytes(out, format!("{json}\n").as_bytes())?;
    }
    if args.json {
        println!("{json}");
    } else {
        print!("{}", report.table());
    }
    Ok(())
}
