//! `msnerf simulate`: writes a synthetic multi-view multispectral dataset from a scene (a built-in name or a
//! YAML file, see `configs/scenes/`), in the spec/dataset.md format. See `msnerf::sim`.

use std::path::PathBuf;

use super::Cli;
use crate::sim::{simulate, PixelFormat, SceneDesc, SimOptions};

#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Scene: a built-in name (campus, ci-small, ci-textured, rig-low, flight-rural, flight-urban) or a YAML file
    #[arg(long)]
    pub scene: String,
    /// Output folder (written atomically; must not exist unless --overwrite)
    #[arg(long)]
    pub out: PathBuf,
    /// Image width in pixels (default: the scene's; height follows its aspect if not given)
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels
    #[arg(long)]
    pub height: Option<u32>,
    /// Total number of views (spread over the scene's orbits)
    #[arg(long)]
    pub views: Option<usize>,
    /// Stored sample type
    #[arg(long, value_enum, default_value_t = PixelFormat::F32)]
    pub format: PixelFormat,
    /// Seed for noise and drift (default: the scene's)
    #[arg(long)]
    pub seed: Option<u64>,
    /// One single-band TIFF per band instead of one multi-band TIFF per view
    #[arg(long)]
    pub band_files: bool,
    /// Worker threads (0 = all cores); the output does not depend on it
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Target number of ground-truth points in ground_truth.ply
    #[arg(long, default_value_t = 200_000)]
    pub points: usize,
    /// Replace an existing output folder
    #[arg(long)]
    pub overwrite: bool,
    /// Also write about this many simulated SfM points with their tracks (sparse_points.json), for depth supervision
    #[arg(long, default_value_t = 0)]
    pub sparse_points: usize,
    /// Position noise of the simulated SfM points (standard deviation, metres)
    #[arg(long, value_parser = super::finite_f64, default_value_t = 0.0)]
    pub sparse_noise: f64,
    /// Shortest track of a simulated SfM point (views that see it)
    #[arg(long, default_value_t = 3)]
    pub sparse_min_views: usize,
    /// Write the flight as this camera's card holds it (raw single-band TIFFs with the maker's EXIF and XMP, a
    /// calibration-panel capture, GPS with noise), the truth beside it; --width/--height resize its sensor
    #[arg(long, value_enum)]
    pub raw_rig: Option<crate::sim::sensor::SensorKind>,
    /// Raw rig: GPS noise per fix, metres (horizontal per axis, vertical)
    #[arg(long, value_delimiter = ',', num_args = 2, value_parser = super::finite_f64, default_values_t = crate::sim::sensor::flight::DEFAULT_GPS_NOISE_M)]
    pub gps_noise: Vec<f64>,
    /// Raw rig: the flight's constant GPS datum shift, metres (east, north, up)
    #[arg(long, value_delimiter = ',', num_args = 3, value_parser = super::finite_f64, default_values_t = crate::sim::sensor::flight::DEFAULT_GPS_SHIFT_M, allow_negative_numbers = true)]
    pub gps_shift: Vec<f64>,
    /// Raw rig: UTC time of the first capture (YYYY:MM:DD HH:MM:SS)
    #[arg(long, default_value = crate::sim::sensor::flight::DEFAULT_START)]
    pub start_time: String,
    /// Raw rig: seconds between captures
    #[arg(long, value_parser = super::positive_f64, default_value_t = 2.0)]
    pub capture_interval: f64,
    /// Raw rig: the firmware version the files carry (default: the camera's current one)
    #[arg(long)]
    pub firmware: Option<String>,
    /// Raw rig: a second calibration-panel capture after the flight
    #[arg(long)]
    pub panel_after: bool,
    /// Raw rig: this many ground control points, surveyed and clicked in the raw images, written as the flight's
    /// gcp_list.txt (OpenDroneMap's layout)
    #[arg(long, default_value_t = 0)]
    pub gcp: usize,
}

pub fn run(_cli: &Cli, a: &SimulateArgs) -> anyhow::Result<()> {
    let scene = SceneDesc::load(&a.scene)?;
    anyhow::ensure!(a.raw_rig.is_some() || a.gcp == 0, "--gcp: ground control is simulated with --raw-rig");
    if let Some(sensor) = a.raw_rig {
        anyhow::ensure!(
            a.sparse_points == 0 && !a.band_files && a.format == PixelFormat::F32,
            "--raw-rig writes the camera's own files: --sparse-points, --band-files and --format do not apply"
        );
        let opts = crate::sim::sensor::RawRigOptions {
            sensor,
            width: a.width,
            height: a.height,
            views: a.views,
            seed: a.seed,
            threads: a.threads,
            overwrite: a.overwrite,
            gps_noise_m: [a.gps_noise[0], a.gps_noise[1]],
            gps_shift_m: [a.gps_shift[0], a.gps_shift[1], a.gps_shift[2]],
            start: a.start_time.clone(),
            interval_s: a.capture_interval,
            firmware: a.firmware.clone(),
            panel_after: a.panel_after,
            points: a.points,
            gcp: a.gcp,
        };
        println!("{}", crate::sim::sensor::simulate_raw_rig(&scene, &opts, &a.out)?);
        return Ok(());
    }
    let opts = SimOptions {
        width: a.width,
        height: a.height,
        views: a.views,
        format: a.format,
        seed: a.seed,
        band_files: a.band_files,
        threads: a.threads,
        points: a.points,
        overwrite: a.overwrite,
        sparse_points: (a.sparse_points > 0).then_some(crate::sim::sparse::SparseOptions {
            count: a.sparse_points,
            noise_m: a.sparse_noise,
            min_views: a.sparse_min_views,
        }),
    };
    let report = simulate(&scene, &opts, &a.out)?;
    println!("{report}");
    Ok(())
}
