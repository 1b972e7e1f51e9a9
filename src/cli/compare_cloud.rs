//! `msnerf compare-cloud --pred A --ref B [--threshold M] [--within LIST] [--standard SPEC] [--json]`:
//! cloud-to-cloud accuracy, completeness, F-score, fractions within thresholds, planar/elevation errors and
//! signed elevation bias (distances to the other cloud's local least-squares plane, `--local-model`), a pass/fail verdict against an RMSE accuracy standard, and per-band reflectance error
//! (see `msnerf::output::compare`). Reads `.ply` and `.las`; needs no GPU.

use std::path::PathBuf;

use crate::output::compare::{
    compare_clouds_with, parse_within, AccuracyOptions, AccuracyStandard, CompareOptions, DistanceModel,
};
use crate::output::pointcloud::read_cloud;

#[derive(clap::Args, Debug)]
pub struct CompareCloudArgs {
    /// The cloud to evaluate (.ply or .las)
    #[arg(long)]
    pub pred: PathBuf,
    /// The reference cloud (.ply or .las), e.g. LiDAR
    #[arg(long = "ref")]
    pub reference: PathBuf,
    /// Distance threshold for precision/recall/F-score and for reflectance pairs, in the clouds' unit
    #[arg(long, value_parser = super::finite_f64, default_value_t = 0.1)]
    pub threshold: f64,
    /// Thresholds (clouds' unit, comma-separated, positive) for the fractions of predicted points (accuracy side)
    /// and of reference points (completeness side) closer than each to the other cloud
    #[arg(long, default_value = "0.1,0.25,0.5,1.0")]
    pub within: String,
    /// Accuracy standard, as the largest RMSEs of the matched pairs (each predicted point and its nearest
    /// reference point), ASPRS-style: planar sqrt(mean(dx²+dy²)), vertical sqrt(mean(dz²)); an axis passes when
    /// its RMSE is at most its limit. A key left out keeps its default (the Multispectral-NeRF paper's)
    #[arg(long, default_value = "planar=0.3,vertical=0.5")]
    pub standard: String,
    /// Distance to the other cloud: `plane` (to the least-squares plane of the --local-k nearest points where it
    /// applies, else to the nearest point; CloudCompare's C2C with a local model) or `none` (nearest point only)
    #[arg(long, default_value = "plane")]
    pub local_model: String,
    /// Neighbours of the local plane
    #[arg(long, default_value_t = 6)]
    pub local_k: usize,
    /// Largest centre-wavelength difference (nm) for pairing bands
    #[arg(long, value_parser = super::finite_f64, default_value_t = 25.0)]
    pub band_tolerance: f64,
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report to this file
    #[arg(long)]
    pub output: Option<PathBuf>,
}

pub fn run(args: &CompareCloudArgs) -> anyhow::Result<()> {
    // Flags first: a typo should not wait for two clouds to load.
    let accuracy = AccuracyOptions {
        within: parse_within(&args.within)?,
        standard: AccuracyStandard::parse(&args.standard)?,
        model: DistanceModel::parse(&args.local_model, args.local_k)?,
    };
    if let Some(out) = &args.output {
        crate::util::atomic::check_not_an_input(out, &[("--pred", &args.pred), ("--ref", &args.reference)])?;
    }
    let pred = read_cloud(&args.pred)?;
    let reference = read_cloud(&args.reference)?;
    let opts = CompareOptions { threshold: args.threshold, band_tolerance_nm: args.band_tolerance };
    let report = compare_clouds_with(&pred, &reference, &opts, &accuracy)?;
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
