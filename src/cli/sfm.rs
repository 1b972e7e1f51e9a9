//! `msnerf sfm DATASET`: COLMAP run for the user (`msnerf::sfm`); prints the report and where the log of each
//! COLMAP step is.

use std::path::PathBuf;

use crate::sfm::images::BandChoice;
use crate::sfm::run::Matcher;
use crate::sfm::{run_sfm, SfmOptions};

#[derive(clap::Args, Debug)]
pub struct SfmArgs {
    /// Dataset folder (or its transforms.json); its transforms.json is kept as transforms.before-poses.json
    pub dataset: PathBuf,
    /// COLMAP binary (default: `colmap` on PATH)
    #[arg(long)]
    pub colmap: Option<PathBuf>,
    /// Band COLMAP sees: a band name or index, `pan` (mean of all bands) or `auto` (the most textured)
    #[arg(long, default_value = "auto")]
    pub band: String,
    /// Integer upsampling of the images COLMAP sees (default: up to 512 px on the longer side, at most 4x)
    #[arg(long)]
    pub upsample: Option<u32>,
    /// Feature matching: auto (exhaustive up to 50 frames, else spatial with GPS or priors, else sequential),
    /// exhaustive, sequential (file-name order) or spatial (nearest by GPS / prior position)
    #[arg(long, value_enum, default_value_t = Matcher::Auto)]
    pub matcher: Matcher,
    /// Frames each frame is matched with: the next ones (sequential) or the nearest ones (spatial)
    #[arg(long, default_value_t = crate::sfm::run::DEFAULT_OVERLAP)]
    pub overlap: usize,
    /// SIFT peak threshold (COLMAP's default 0.0067 finds too few features in small aerial views; docs/poses.md)
    #[arg(long, value_parser = super::finite_f64, default_value_t = crate::sfm::run::DEFAULT_PEAK_THRESHOLD)]
    pub peak_threshold: f64,
    /// Most SIFT features per image (default: one per 150 pixels of the upsampled image, 1024 to 8192); CPU
    /// matching time grows with its square
    #[arg(long)]
    pub max_features: Option<usize>,
    /// Let bundle adjustment refine the dataset's focal length and distortion
    #[arg(long)]
    pub refine_intrinsics: bool,
    /// Projected CRS to geo-register into (EPSG:n; default: the dataset's crs, else the first GPS fix's UTM zone)
    #[arg(long)]
    pub crs: Option<String>,
    /// Keep COLMAP's own frame even when the frames carry GPS
    #[arg(long)]
    pub no_georef: bool,
    /// GPS noise floor for the robust geo-registration, metres
    #[arg(long, value_parser = super::finite_f64, default_value_t = crate::sfm::run::DEFAULT_GPS_ERROR_M)]
    pub gps_error: f64,
    /// With ground control: keep the similarity fit alone, without the bundle adjustment on the control points
    #[arg(long)]
    pub no_adjust: bool,
    /// Threads for COLMAP (default: all cores)
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print the report as JSON
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: &SfmArgs) -> anyhow::Result<()> {
    anyhow::ensure!(a.peak_threshold > 0.0 && a.peak_threshold.is_finite(), "--peak-threshold must be > 0");
    anyhow::ensure!(a.gps_error > 0.0 && a.gps_error.is_finite(), "--gps-error must be > 0");
    anyhow::ensure!(a.overlap > 0, "--overlap must be > 0");
    let mut o = SfmOptions::new(&a.dataset);
    o.colmap = a.colmap.clone();
    o.band = BandChoice::parse(&a.band);
    o.upsample = a.upsample;
    o.matcher = a.matcher;
    o.overlap = a.overlap;
    o.peak_threshold = a.peak_threshold;
    if let Some(m) = a.max_features {
        anyhow::ensure!((64..=65536).contains(&m), "--max-features must be 64..=65536, got {m}");
        o.max_features = Some(m);
    }
    o.refine_intrinsics = a.refine_intrinsics;
    o.crs = a.crs.as_deref().map(crate::geo::Crs::parse).transpose().map_err(|e| anyhow::anyhow!("--crs: {e}"))?;
    o.no_georef = a.no_georef;
    o.gps_error_m = a.gps_error;
    o.no_adjust = a.no_adjust;
    if let Some(t) = a.threads {
        anyhow::ensure!(t > 0, "--threads must be > 0");
        o.threads = t;
    }
    let r = run_sfm(&o)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    println!(
        "{} on {} frames: band {}, upsampled {}x, {:?} matching, intrinsics {}",
        r.colmap, r.frames, r.band, r.upsample, r.matcher, r.intrinsics
    );
    println!("registered {} of {} frames; {} sparse points", r.registered, r.frames, r.points);
    if let (Some(e), Some(t)) = (r.mean_reprojection_error_px, r.mean_track_length) {
        println!("mean reprojection error {e:.3} px, mean track length {t:.2}");
    }
    if r.models.len() > 1 {
        println!("COLMAP made {} models ({:?} images): the largest is used", r.models.len(), r.models);
    }
    for f in &r.unregistered {
        println!("not registered (moved to unregistered_frames, unused): {f}");
    }
    match (&r.georef, &r.crs) {
        (Some(g), Some(c)) => {
            println!("geo-registered in {c}:");
            for l in g.describe() {
                println!("  {l}");
            }
        }
        _ => println!("no GPS: the poses are in COLMAP's own frame (arbitrary scale; no crs)"),
    }
    let mut secs: Vec<_> = r.seconds.iter().collect();
    secs.sort_by(|a, b| a.0.cmp(b.0));
    println!("seconds: {}", secs.iter().map(|(k, v)| format!("{k} {v:.1}")).collect::<Vec<_>>().join(", "));
    println!("COLMAP workspace and logs: {}", r.workspace.display());
    if let Some(b) = &r.backup {
        println!("previous transforms.json kept as {}", b.display());
    }
    Ok(())
}
