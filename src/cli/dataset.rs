//! `msnerf dataset check DIR`: frames, splits, bands, image size and sample type, per-band value ranges, scene bounds,
//! and the host memory a full load needs against what the cache will use; a non-zero exit on any problem.

use super::Cli;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct DatasetArgs {
    #[command(subcommand)]
    pub what: DatasetWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum DatasetWhat {
    /// Check a dataset folder and report what it holds
    Check {
        /// Dataset folder (transforms.json)
        dir: PathBuf,
        /// Host memory the image cache may use, in GiB
        #[arg(long, default_value_t = 8.0)]
        host_budget_gib: f64,
        /// Print JSON
        #[arg(long)]
        json: bool,
        /// Report outlying camera centres as left out instead of as problems
        #[arg(long)]
        drop_outliers: bool,
    },
}

pub fn run(_cli: &Cli, a: &DatasetArgs) -> anyhow::Result<()> {
    let DatasetWhat::Check { dir, host_budget_gib, json, drop_outliers } = &a.what;
    let opts = crate::data::LoadOptions { drop_outliers: *drop_outliers, ..Default::default() };
    let report = crate::data::check::check_dataset_with(dir, (host_budget_gib * (1u64 << 30) as f64) as u64, &opts);
    if *json {
        println!("{}", report.to_json());
    } else {
        print!("{report}");
    }
    anyhow::ensure!(report.is_ok(), "{}: the dataset has problems (listed above)", dir.display());
    Ok(())
}
