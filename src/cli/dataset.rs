//! `msnerf dataset check DIR`: frames, splits, bands, image size and sample type, per-band value ranges, scene bounds,
//! and the host memory a full load needs against what the cache will use; a non-zero exit on any problem.
//! `msnerf dataset register IN --out OUT`: band-to-band registration of a dataset in msnerf's format
//! ([`crate::rig::register_dataset`]).

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
    /// Register every band of every frame to a reference band (homography alignment, as `import rig` does) and
    /// write a new dataset without `rig_cameras`
    Register {
        /// Dataset folder (transforms.json)
        dir: PathBuf,
        /// Output dataset folder (must not exist unless --overwrite)
        #[arg(long)]
        out: PathBuf,
        /// Reference band by name (default: the one nearest 560 nm among the bands seen by the frame camera)
        #[arg(long)]
        reference_band: Option<String>,
        /// Also fit the residual shift field on top of each homography
        #[arg(long)]
        field: bool,
        /// One warp per band for every frame (the median of the frames' own), as `import rig --register rig`
        #[arg(long)]
        shared: bool,
        /// Replace OUT when it exists
        #[arg(long)]
        overwrite: bool,
    },
}

pub fn run(_cli: &Cli, a: &DatasetArgs) -> anyhow::Result<()> {
    let (dir, host_budget_gib, json, drop_outliers) = match &a.what {
        DatasetWhat::Check { dir, host_budget_gib, json, drop_outliers } => (dir, host_budget_gib, json, drop_outliers),
        DatasetWhat::Register { dir, out, reference_band, field, shared, overwrite } => {
            let opts = crate::rig::register_dataset::RegisterOptions {
                reference_band: reference_band.clone(),
                field: *field,
                shared: *shared,
                overwrite: *overwrite,
            };
            let s = crate::rig::register_dataset::register_dataset(dir, out, &opts)?;
            println!("{}", serde_json::to_string_pretty(&s)?);
            return Ok(());
        }
    };
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
