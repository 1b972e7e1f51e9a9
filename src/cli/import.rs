//! `msnerf import rig DIR --out DATASET`: raw single-band rig TIFFs -> calibrated, registered dataset
//! (library: `crate::rig`). Prints a summary: captures, bands, calibration, skipped files, warnings, speed.

use std::path::PathBuf;

use crate::rig::ground_control::GcpSource;
use crate::rig::{import_rig, ImportOptions, IrradianceSource, Registration, Units};

#[derive(clap::Args, Debug)]
pub struct ImportArgs {
    #[command(subcommand)]
    pub what: ImportWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum ImportWhat {
    /// A flight folder of raw single-band rig TIFFs (MicaSense, DJI P4M/M3M, Pix4D-XMP rigs)
    Rig(RigArgs),
    /// Camera poses, intrinsics and sparse points from a photogrammetry tool into a dataset (docs/poses.md)
    Poses(PosesArgs),
}

#[derive(clap::Args, Debug)]
pub struct PosesArgs {
    /// Where the poses come from
    #[arg(long, value_enum)]
    pub from: crate::poses::PoseFormat,
    /// The model: COLMAP's sparse model folder (e.g. sparse/0), OpenSfM's reconstruction.json, the ODM project
    /// folder, or Metashape's cameras XML
    pub model: PathBuf,
    /// The dataset to put them in (its transforms.json is kept as transforms.before-poses.json)
    pub dataset: PathBuf,
    /// Projected CRS for a georeferenced Metashape chunk (EPSG:n; default: the cameras' WGS 84 UTM zone)
    #[arg(long)]
    pub crs: Option<String>,
    /// Print the report as JSON
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct RigArgs {
    /// Flight folder (searched recursively for .tif/.tiff; only read, never written)
    pub dir: PathBuf,
    /// Dataset folder to write (written atomically)
    #[arg(long)]
    pub out: PathBuf,
    /// A band file of each calibration-panel capture (its other bands are found by capture id)
    #[arg(long, num_args = 1..)]
    pub panel: Vec<PathBuf>,
    /// Panel reflectance from its calibration sheet: one value, or one per band in wavelength order
    #[arg(long, value_delimiter = ',')]
    pub panel_reflectance: Vec<f64>,
    /// Panel corners in pixels (x1,y1,x2,y2,x3,y3,x4,y4) instead of detecting the panel
    #[arg(long, value_delimiter = ',')]
    pub panel_corners: Vec<f64>,
    /// Irradiance source for reflectance
    #[arg(long, value_enum, default_value_t = IrradianceSource::Auto)]
    pub irradiance: IrradianceSource,
    /// Output units (radiance stops before the irradiance)
    #[arg(long, value_enum, default_value_t = Units::Reflectance)]
    pub units: Units,
    /// Keep the raw lens geometry (the distortion goes into transforms.json)
    #[arg(long)]
    pub no_undistort: bool,
    /// Band-to-band registration: per capture, one shared rig warp, or the rig data only
    #[arg(long, value_enum, default_value_t = Registration::Auto)]
    pub register: Registration,
    /// Captures the shared rig warps are estimated on (`--register rig`)
    #[arg(long, default_value_t = crate::rig::import::REGISTER_SAMPLE)]
    pub register_sample: usize,
    /// Skip band-to-band registration (same as `--register none`)
    #[arg(long)]
    pub no_register: bool,
    /// Keep every band in its own camera (undistorted, unwarped) and write the rig's geometry from the XMP
    /// (`Camera:RigRelatives`, `RigTranslations`) as `rig_cameras`, for rig-aware training (docs/dataset.md)
    #[arg(long)]
    pub rig_cameras: bool,
    /// Band the others are registered to (default: the one nearest 560 nm)
    #[arg(long)]
    pub reference_band: Option<String>,
    /// Projected CRS of the GPS pose priors and the dataset's `crs` (EPSG:n or OGC WKT; default: the WGS 84 UTM
    /// zone of the first capture with GPS)
    #[arg(long)]
    pub crs: Option<String>,
    /// Ground control points in OpenDroneMap's gcp_list.txt layout, pixels in the raw band files (default: DIR's
    /// gcp_list.txt when there is one)
    #[arg(long, conflicts_with = "no_gcp")]
    pub gcp: Option<PathBuf>,
    /// Ignore DIR's gcp_list.txt
    #[arg(long)]
    pub no_gcp: bool,
    /// Replace an existing output folder
    #[arg(long)]
    pub overwrite: bool,
    /// Worker threads (default: all cores)
    #[arg(long)]
    pub threads: Option<usize>,
}

fn run_poses(p: &PosesArgs) -> anyhow::Result<()> {
    let crs = p.crs.as_deref().map(crate::geo::Crs::parse).transpose().map_err(|e| anyhow::anyhow!("--crs: {e}"))?;
    anyhow::ensure!(
        crs.is_none() || p.from == crate::poses::PoseFormat::Metashape,
        "--crs: only a georeferenced Metashape chunk (ECEF) is projected on import; COLMAP, OpenSfM and ODM poses \
         stay in the model's own frame"
    );
    let model = p.from.read(&p.model, crs.as_ref())?;
    let rep = crate::poses::apply_poses(&model, &p.model, &p.dataset)?;
    if p.json {
        println!("{}", serde_json::to_string_pretty(&rep)?);
        return Ok(());
    }
    println!("{}: {} of {} frames posed from {}", p.dataset.display(), rep.registered, rep.frames, rep.source);
    if let (Some(e), Some(t)) = (rep.mean_reprojection_error_px, rep.mean_track_length) {
        println!("sparse points: {} (mean reprojection error {e:.3} px, mean track length {t:.1})", rep.points);
    }
    for f in &rep.unregistered {
        println!("not registered (moved to unregistered_frames): {f}");
    }
    for i in &rep.unknown_images {
        println!("model image not in the dataset: {i}");
    }
    for n in &rep.notes {
        println!("note: {n}");
    }
    match (&rep.crs, &rep.crs_removed) {
        (Some(c), _) => println!("poses in {c}: the dataset's crs"),
        (None, Some(old)) => {
            println!("crs {old} removed: the model is not georeferenced, so its poses are in a local frame")
        }
        (None, None) => println!("the model is not georeferenced: the poses are in its local frame (no crs)"),
    }
    if let Some(b) = &rep.backup {
        println!("previous transforms.json kept as {}", b.display());
    }
    Ok(())
}

pub fn run(a: &ImportArgs) -> anyhow::Result<()> {
    let r = match &a.what {
        ImportWhat::Rig(r) => r,
        ImportWhat::Poses(p) => return run_poses(p),
    };
    let panel_corners = match r.panel_corners.len() {
        0 => None,
        8 => {
            let c = &r.panel_corners;
            Some([[c[0], c[1]], [c[2], c[3]], [c[4], c[5]], [c[6], c[7]]])
        }
        n => anyhow::bail!("--panel-corners: {n} numbers given, 8 expected (x1,y1,...,x4,y4)"),
    };
    let threads = r.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let opts = ImportOptions {
        input: r.dir.clone(),
        out: r.out.clone(),
        panel_files: r.panel.clone(),
        panel_reflectance: r.panel_reflectance.clone(),
        panel_corners,
        irradiance: r.irradiance,
        units: r.units,
        undistort: !r.no_undistort,
        registration: if r.no_register { Registration::None } else { r.register },
        register_sample: r.register_sample,
        reference_band: r.reference_band.clone(),
        crs: r.crs.as_deref().map(crate::geo::Crs::parse).transpose().map_err(|e| anyhow::anyhow!("--crs: {e}"))?,
        overwrite: r.overwrite,
        threads,
        progress: true,
        rig_cameras: r.rig_cameras,
        ground_control: GcpSource::from_flags(r.gcp.as_ref(), r.no_gcp),
    };
    let s = import_rig(&opts)?;
    println!("wrote {} ({} captures, bands {})", r.out.display(), s.captures, s.bands.join(", "));
    println!("units: {:?}, irradiance from: {}", s.units, s.calibration);
    if let Some(p) = &s.panel {
        for (bi, e) in p.irradiance.iter().enumerate() {
            let back: Vec<String> = p.captures.iter().map(|c| format!("{:.4}", c[bi].reflectance_back)).collect();
            println!("  {}: irradiance {e:.5}, panel reflectance back {}", s.bands[bi], back.join(", "));
        }
    }
    println!("registration ({:?}): largest residual {:.3} px", s.registration, s.max_residual_px);
    if let Some(sp) = &s.rig_spread_px {
        let v: Vec<String> = s.bands.iter().zip(sp).map(|(b, v)| format!("{b} {v:.2}")).collect();
        println!("  shared rig warps; spread over the sampled captures (px): {}", v.join(", "));
    }
    println!("{:.1} s, {:.2} captures/s", s.seconds, s.captures_per_second);
    for k in &s.skipped {
        println!("skipped {}: {}", k.what, k.reason);
    }
    for w in &s.warnings {
        println!("warning: {w}");
    }
    Ok(())
}
