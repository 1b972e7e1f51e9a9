//! `msnerf compare-cloud --pred A --ref B [--threshold M] [--json]`: cloud-to-cloud accuracy, completeness,
//! F-score, planar/elevation errors and per-band reflectance error (see `msnerf::output::compare`). Reads
//! `.ply` and `.las`; needs no GPU.

use std::path::PathBuf;

use crate::output::compare::{compare_clouds, CompareOptions};
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
    #[arg(long, default_value_t = 0.1)]
    pub threshold: f64,
    /// Largest centre-wavelength difference (nm) for pairing bands
    #[arg(long, default_value_t = 25.0)]
    pub band_tolerance: f64,
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON report to this file
    #[arg(long)]
    pub output: Option<PathBuf>,
}

pub fn run(args: &CompareCloudArgs) -> anyhow::Result<()> {
    let pred = read_cloud(&args.pred)?;
    let reference = read_cloud(&args.reference)?;
    let opts = CompareOptions { threshold: args.threshold, band_tolerance_nm: args.band_tolerance };
    let report = compare_clouds(&pred, &reference, &opts)?;
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
