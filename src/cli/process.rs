//! `msnerf process FLIGHT_DIR --out PROJECT`: the flight from the camera's card to the survey products and a report
//! in one command (see `msnerf::process`): parse, call, print.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::Cli;
use crate::output::raster::indices::VegetationIndex;
use crate::process::{process, ProcessOptions, Stage};
use crate::rig::{IrradianceSource, Units};

#[derive(clap::Args, Debug)]
pub struct ProcessArgs {
    /// The flight folder: the camera's card as it came out of the camera (MicaSense 0000SET/..., DJI_...), with its
    /// calibration-panel captures
    pub flight: PathBuf,
    /// Project folder (created; a rerun resumes it, skipping the stages that are current)
    #[arg(long)]
    pub out: PathBuf,
    /// The calibration panel's reflectance from its sheet: one value, or one per band in wavelength order (without
    /// it the light sensor calibrates)
    #[arg(long, value_delimiter = ',', value_parser = super::finite_f64)]
    pub panel_reflectance: Vec<f64>,
    /// Irradiance from the panel captures, the light sensor, or the panel when there is one
    #[arg(long, value_enum, default_value_t = IrradianceSource::Auto)]
    pub irradiance: IrradianceSource,
    /// Reflectance (default) or radiance
    #[arg(long, value_enum, default_value_t = Units::Reflectance)]
    pub units: Units,
    /// The band the others are registered to (default: the band nearest 560 nm)
    #[arg(long)]
    pub reference_band: Option<String>,
    /// Projected CRS of the outputs (EPSG:n; default: the flight's WGS 84 UTM zone)
    #[arg(long)]
    pub crs: Option<String>,
    /// Ground control points in OpenDroneMap's gcp_list.txt layout, pixels in the raw band files (default: the
    /// flight folder's gcp_list.txt when there is one); they fix the georeferencing, their residuals go in the report
    #[arg(long, conflicts_with = "no_gcp")]
    pub gcp: Option<PathBuf>,
    /// Ignore the flight folder's gcp_list.txt
    #[arg(long)]
    pub no_gcp: bool,
    /// Poses from another tool instead of COLMAP: its model (with --poses-from)
    #[arg(long, requires = "poses_from")]
    pub poses: Option<PathBuf>,
    /// The tool --poses comes from
    #[arg(long, value_enum, requires = "poses")]
    pub poses_from: Option<crate::poses::PoseFormat>,
    /// Model profile or YAML file (`auto`: multispectral-nerf on a GPU, demo on a CPU device)
    #[arg(long, default_value = "auto")]
    pub model: String,
    /// Hardware profile (rtx2080ti-11gb, a100-80gb, lavapipe, a YAML file) or `auto` (this device through the planner)
    #[arg(long, default_value = "auto")]
    pub hardware: String,
    /// Seconds of training (default: the profile's steps on a GPU, 900 s on a CPU device)
    #[arg(long, value_parser = super::positive_f64)]
    pub time_budget: Option<f64>,
    #[arg(long)]
    pub max_steps: Option<u64>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Train on the images alone (no depth supervision from the sparse points)
    #[arg(long)]
    pub images_only: bool,
    /// Cell size of the DSM and ortho in world units (default: the flight's ground sampling distance)
    #[arg(long, value_parser = super::positive_f64)]
    pub gsd: Option<f64>,
    /// Training rays rendered for the point cloud
    #[arg(long, default_value_t = crate::nerf::export::ExportOptions::default().rays)]
    pub cloud_rays: usize,
    /// Vegetation indices written beside the ortho (comma-separated)
    #[arg(long, value_delimiter = ',', default_values_t = ["ndvi".to_string(), "ndre720".to_string()])]
    pub indices: Vec<String>,
    /// DSM cells without photometric support and gaps: `auto` interpolates the gaps and the cells whose field height
    /// agrees with the interpolation and keeps the field's height where it stands out (crowns); or all interpolated
    /// from the measured cells around them, the field's height, or nodata (dsm_quality.tif says which each cell is)
    #[arg(long, value_enum, default_value_t = crate::nerf::survey::DsmFill::default())]
    pub fill: crate::nerf::survey::DsmFill,
    /// Stop after this stage
    #[arg(long, value_enum)]
    pub stop_after: Option<Stage>,
    /// Make this stage and every later one again, even where current
    #[arg(long, value_enum)]
    pub redo: Option<Stage>,
    /// Worker threads for import and COLMAP (default: all cores)
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(cli: &Cli, a: &ProcessArgs) -> anyhow::Result<()> {
    let indices = a.indices.iter().map(|s| VegetationIndex::parse(s)).collect::<Result<Vec<_>, _>>()?;
    let crs = a.crs.as_deref().map(crate::geo::Crs::parse).transpose().map_err(|e| anyhow::anyhow!("--crs: {e}"))?;
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let _ = ctrlc::set_handler(move || s2.store(true, std::sync::atomic::Ordering::Relaxed));
    let o = ProcessOptions {
        flight: a.flight.clone(),
        project: a.out.clone(),
        panel_reflectance: a.panel_reflectance.clone(),
        irradiance: a.irradiance,
        units: a.units,
        reference_band: a.reference_band.clone(),
        crs,
        ground_control: crate::rig::ground_control::GcpSource::from_flags(a.gcp.as_ref(), a.no_gcp),
        poses: a.poses_from.zip(a.poses.clone()),
        model: a.model.clone(),
        hardware: a.hardware.clone(),
        time_budget_s: a.time_budget,
        max_steps: a.max_steps,
        seed: a.seed,
        images_only: a.images_only,
        gsd: a.gsd,
        cloud_rays: a.cloud_rays,
        indices,
        fill: a.fill,
        stop_after: a.stop_after,
        redo: a.redo,
        threads: a.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)),
        device: cli.context_desc(),
        stop: Some(stop),
    };
    let s = process(&o, &mut |line| println!("{line}"))?;
    match &s.report {
        Some(r) => println!("report: {}", r.display()),
        None => println!("project: {} (no report yet)", s.project.display()),
    }
    Ok(())
}
