//! The `msnerf` command line: one module per subcommand; `main.rs` only parses and dispatches.

pub mod bench;
pub mod compare_cloud;
pub mod compare_raster;
pub mod compare_trees;
pub mod dataset;
pub mod demo;
pub mod devices;
pub mod eval;
pub mod export;
pub mod export_canopy;
pub mod export_survey;
pub mod import;
pub mod partition;
pub mod plan;
pub mod preview;
pub mod process;
pub mod reference;
pub mod refine_args;
pub mod render;
pub mod sfm;
pub mod simulate;
pub mod sweep;
pub mod train;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(name = "msnerf", version, about = "Multispectral neural radiance fields on Vulkan compute")]
pub struct Cli {
    /// Vulkan device: index as `msnerf devices` lists them, or part of its name [env: MSNERF_DEVICE]
    #[arg(long, global = true)]
    pub device: Option<String>,
    /// Enable the Khronos validation layer (slow; for debugging) [env: MSNERF_VALIDATION]
    #[arg(long, global = true)]
    pub validation: bool,
    /// More log output (-v info, -vv debug)
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// List Vulkan devices and their capabilities
    Devices(devices::DevicesArgs),
    /// Train a model on a dataset
    Train(train::TrainArgs),
    /// Evaluate a trained run: PSNR and SSIM per band and per view (LPIPS given its weights)
    Eval(eval::EvalArgs),
    /// Render views of a trained run: GeoTIFFs, previews, vegetation indices
    Render(render::RenderArgs),
    /// Export a multispectral point cloud from a trained run
    Export(export::ExportArgs),
    /// Import raw captures: `import rig DIR --out DATASET` (raw multispectral rig TIFFs to reflectance)
    Import(import::ImportArgs),
    /// The whole flight in one command: raw camera files -> dataset -> poses -> training -> cloud, DSM, ortho, indices
    /// and a processing report (resumable; each stage skipped when current)
    Process(process::ProcessArgs),
    /// Camera poses by running COLMAP on a dataset (geo-registered to the frames' GPS when they have it)
    Sfm(sfm::SfmArgs),
    /// Dataset tools (check, register)
    Dataset(dataset::DatasetArgs),
    /// The whole job on a built-in simulated scene: simulate, train, evaluate, render, export, compare
    Demo(demo::DemoArgs),
    /// Benchmarks that print numbers (kernels, training steps)
    Bench(bench::BenchArgs),
    /// Write a synthetic multispectral dataset from a scene (built-in name or YAML file)
    Simulate(simulate::SimulateArgs),
    /// Plan GPU and host memory for training a model on a hardware profile (VRAM budget planner)
    Plan(plan::PlanArgs),
    /// Compare a point cloud against a reference (accuracy, completeness, F-score, per-band error)
    CompareCloud(compare_cloud::CompareCloudArgs),
    /// PNG previews of a GeoTIFF: hillshade and height colours for one band, natural colour, CIR and NDVI for many
    Preview(preview::PreviewArgs),
    /// Compare a DSM or orthomosaic GeoTIFF against a reference raster (per band, per class)
    CompareRaster(compare_raster::CompareRasterArgs),
    /// Compare trees found by `export trees` against known trees (detection, false trees, heights)
    CompareTrees(compare_trees::CompareTreesArgs),
    /// Train a grid of configurations under one budget: accuracy against time, CSV, plots and a report
    Sweep(sweep::SweepArgs),
    /// Split a large flight into a grid of overlapping blocks, each a dataset of its own
    Partition(partition::PartitionArgs),
    /// Train every block of a `partition` folder, one `msnerf train` process per block, resumable
    TrainBlocks(partition::TrainBlocksArgs),
}

impl Cli {
    /// The context description from flags, falling back to the environment.
    pub fn context_desc(&self) -> crate::gpu::ContextDesc {
        let mut d = crate::gpu::ContextDesc::from_env();
        if self.device.is_some() {
            d.device = self.device.clone();
        }
        if self.validation && d.validation == crate::gpu::Validation::Off {
            d.validation = crate::gpu::Validation::IfAvailable;
        }
        d
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match &cli.command {
        Command::Devices(a) => devices::run(&cli, a),
        Command::Bench(a) => bench::run(&cli, a),
        Command::Train(a) => train::run(&cli, a),
        Command::Eval(a) => eval::run(&cli, a),
        Command::Render(a) => render::run(&cli, a),
        Command::Export(a) => export::run(&cli, a),
        Command::Dataset(a) => dataset::run(&cli, a),
        Command::Import(a) => import::run(a),
        Command::Sfm(a) => sfm::run(a),
        Command::Process(a) => process::run(&cli, a),
        Command::Demo(a) => demo::run(&cli, a),
        Command::Simulate(a) => simulate::run(&cli, a),
        Command::CompareCloud(a) => compare_cloud::run(a),
        Command::CompareRaster(a) => compare_raster::run(a),
        Command::CompareTrees(a) => compare_trees::run(a),
        Command::Preview(a) => preview::run(a),
        Command::Plan(a) => plan::run(&cli, a),
        Command::Sweep(a) => sweep::run(&cli, a),
        Command::Partition(a) => partition::run_partition(a),
        Command::TrainBlocks(a) => partition::run_train_blocks(a),
    }
}

/// Clap value parser for a real-valued flag: a finite number (`nan` and `inf` are refused with the flag's name).
pub fn finite_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("{s:?} is not a number ({e})"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s:?} is not a finite number"))
    }
}

/// [`finite_f64`] for an f32 flag.
pub fn finite_f32(s: &str) -> Result<f32, String> {
    let v = finite_f64(s)? as f32;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s:?} is beyond the range of a 32-bit float"))
    }
}

/// Clap value parser for an opacity threshold (`--min-accumulation`): a number in [0, 1].
pub fn opacity_f32(s: &str) -> Result<f32, String> {
    let v = finite_f32(s)?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is not an opacity in [0, 1]"))
    }
}

/// Clap value parser for a positive real-valued flag (a time or memory budget): finite and above 0.
pub fn positive_f64(s: &str) -> Result<f64, String> {
    let v = finite_f64(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("{v} is not positive"))
    }
}

/// Clap value parser for a share: a number in [0, 1].
pub fn unit_f64(s: &str) -> Result<f64, String> {
    let v = finite_f64(s)?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is not a share in [0, 1]"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_flags_refuse_nan_inf_and_non_positive_budgets() {
        assert_eq!(finite_f64("-2.5"), Ok(-2.5));
        assert_eq!(positive_f64("30"), Ok(30.0));
        for bad in ["nan", "NaN", "inf", "-inf", "1e400", "x", ""] {
            assert!(finite_f64(bad).is_err(), "{bad}");
            assert!(positive_f64(bad).is_err(), "{bad}");
        }
        for bad in ["0", "-1", "-0.0"] {
            assert!(positive_f64(bad).is_err(), "{bad}");
        }
        assert_eq!(finite_f32("0.5"), Ok(0.5));
        assert!(finite_f32("1e39").is_err(), "finite as f64, infinite as f32");
        assert_eq!(opacity_f32("1"), Ok(1.0));
        assert!(opacity_f32("2").is_err() && opacity_f32("-0.1").is_err());
    }
}
