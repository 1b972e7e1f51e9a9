//! [`process`]: a flight folder to survey products in one call, stage by stage ([`super::stage`]), each stage
//! calling the same library functions as its per-step command (`import rig`, `sfm` / `import poses`, `dataset
//! check`, `train`, `eval`, `export pointcloud`, `export dsm` + `ortho`), then the report ([`super::report`]).
//!
//! Project layout:
//!
//! ```text
//! PROJECT/dataset/          the imported dataset (transforms.import.json: as imported; transforms.json: posed)
//! PROJECT/check.json        dataset check
//! PROJECT/run/              the trained run (checkpoints, metrics, eval.json)
//! PROJECT/products/         cloud.las, dsm.tif, ortho.tif, ortho_<index>.tif, their previews
//! PROJECT/report.html       the processing report
//! PROJECT/stages/*.json     what each stage did (module [`super::stage`])
//! ```

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use serde_json::json;

use super::error::ProcessError;
use super::stage::{
    freshness, read_record, remove_record, stamp, stamps_fingerprint, write_record, Freshness, Stage, StageRecord,
};
use crate::gpu::{Context, ContextDesc};
use crate::output::raster::indices::VegetationIndex;
use crate::rig::{IrradianceSource, Units};

/// Everything `msnerf process` takes.
#[derive(Debug, Clone)]
pub struct ProcessOptions {
    pub flight: PathBuf,
    pub project: PathBuf,
    /// Import: the panel's reflectance (one value, or one per band by wavelength), the irradiance source, units.
    pub panel_reflectance: Vec<f64>,
    pub irradiance: IrradianceSource,
    pub units: Units,
    pub reference_band: Option<String>,
    pub crs: Option<crate::geo::Crs>,
    /// Ground control points (default: the flight folder's `gcp_list.txt` when it has one).
    pub ground_control: crate::rig::ground_control::GcpSource,
    /// Poses from another tool instead of COLMAP: its format and its model.
    pub poses: Option<(crate::poses::PoseFormat, PathBuf)>,
    /// Training: a profile name or file, or `auto` (multispectral-nerf on a GPU, demo on a CPU device).
    pub model: String,
    /// A hardware profile or `auto` (this device's memory through the planner).
    pub hardware: String,
    /// Seconds of training (default: the profile's steps on a GPU, [`CPU_TIME_BUDGET_S`] on a CPU device).
    pub time_budget_s: Option<f64>,
    pub max_steps: Option<u64>,
    pub seed: Option<u64>,
    /// No depth supervision from the sparse points.
    pub images_only: bool,
    /// Products: cell size of the DSM and ortho (default: the flight's ground sampling distance), rays of the
    /// point cloud, vegetation indices beside the ortho.
    pub gsd: Option<f64>,
    pub cloud_rays: usize,
    pub indices: Vec<VegetationIndex>,
    /// What the DSM makes of cells without photometric support.
    pub fill: crate::nerf::survey::DsmFill,
    /// Stop after this stage.
    pub stop_after: Option<Stage>,
    /// Run this stage and every later one again even where current.
    pub redo: Option<Stage>,
    pub threads: usize,
    pub device: ContextDesc,
    /// Ctrl-C: training saves and stops; the run stops after the current stage.
    pub stop: Option<Arc<AtomicBool>>,
}

/// Training on a CPU device (lavapipe) is limited to this many seconds unless `--time-budget` says otherwise.
pub const CPU_TIME_BUDGET_S: f64 = 900.0;

/// What happened to each stage.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StageOutcome {
    pub stage: Stage,
    /// `ran`, `current` (skipped) or `not run` (after --stop-after).
    pub status: String,
    pub seconds: f64,
}

/// The whole run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ProcessSummary {
    pub project: PathBuf,
    pub stages: Vec<StageOutcome>,
    pub report: Option<PathBuf>,
}

/// Messages for the caller's progress lines.
pub type Progress<'a> = &'a mut dyn FnMut(&str);

fn rel(p: &str) -> PathBuf {
    PathBuf::from(p)
}

/// The fingerprint of the flight folder: every TIFF's path, size and modification time (not their content: a
/// flight is gigabytes).
fn flight_fingerprint(flight: &Path) -> Result<String, ProcessError> {
    let files = crate::rig::capture::list_tiffs(flight).map_err(|e| ProcessError::stage(Stage::Import)(&e))?;
    let mut list = Vec::with_capacity(files.len());
    for f in files {
        let m = std::fs::metadata(&f).map_err(ProcessError::io(&f))?;
        let t =
            m.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos());
        list.push(format!("{}\t{}\t{t}", f.strip_prefix(flight).unwrap_or(&f).display(), m.len()));
    }
    Ok(super::stage::sha256_hex(list.join("\n").as_bytes()))
}

/// Runs the stages that are not current (module doc). `progress` gets one line per stage and its news.
pub fn process(o: &ProcessOptions, progress: Progress) -> Result<ProcessSummary, ProcessError> {
    validate(o)?;
    std::fs::create_dir_all(&o.project).map_err(ProcessError::io(&o.project))?;
    let project = &o.project;
    let mut upstream: Vec<(Stage, String)> = Vec::new();
    let mut outcomes = Vec::new();
    let mut rerun_rest = false;
    let flight_fp = flight_fingerprint(&o.flight)?;
    for stage in Stage::ALL {
        if o.stop_after.is_some_and(|s| stage > s) {
            outcomes.push(StageOutcome { stage, status: "not run".into(), seconds: 0.0 });
            continue;
        }
        if o.stop.as_ref().is_some_and(|s| s.load(std::sync::atomic::Ordering::Relaxed)) {
            return Err(ProcessError::Stage {
                stage: stage.name().into(),
                reason: "interrupted before it started".into(),
            });
        }
        let inputs = stage_inputs(o, stage, &flight_fp, &upstream);
        let record = read_record(project, stage)?;
        let fresh = freshness(project, record.as_ref(), &inputs)?;
        let n = format!("[{}/{}] {}", stage.index() + 1, Stage::ALL.len(), stage.name());
        let forced = rerun_rest || o.redo.is_some_and(|r| stage >= r);
        match (&fresh, forced) {
            (Freshness::Current, false) => {
                let r = record.expect("current means recorded");
                progress(&format!("{n}: current (made in {:.0} s), skipped", r.seconds));
                upstream.push((stage, r.outputs_fingerprint.clone()));
                outcomes.push(StageOutcome { stage, status: "current".into(), seconds: 0.0 });
                continue;
            }
            (Freshness::Edited(file, what), false) => {
                return Err(ProcessError::Edited {
                    stage: stage.name().into(),
                    file: file.clone(),
                    what: what.clone(),
                });
            }
            _ => {}
        }
        // This stage runs: every later one runs too, and none of their old records may be taken for current.
        rerun_rest = true;
        for later in Stage::ALL.iter().filter(|s| **s >= stage) {
            remove_record(project, *later)?;
        }
        progress(&format!("{n}: {}", describe(stage, o)));
        crate::util::mem::reset_peak_rss();
        let children_before = crate::util::mem::children_peak_rss_bytes();
        let t0 = Instant::now();
        let done = run_stage(o, stage, &inputs, progress)?;
        let seconds = t0.elapsed().as_secs_f64();
        let outputs = stamp(project, &done.outputs)?;
        let record = StageRecord {
            stage,
            msnerf: env!("CARGO_PKG_VERSION").into(),
            inputs,
            outputs_fingerprint: stamps_fingerprint(&outputs),
            outputs,
            finished_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
            seconds,
            // The process's own peak, or a child's (COLMAP) when one ran in this stage and needed more.
            peak_host_bytes: {
                let own = crate::util::mem::peak_rss_bytes();
                let child = crate::util::mem::children_peak_rss_bytes().filter(|c| Some(*c) != children_before);
                own.max(child)
            },
            peak_gpu_bytes: done.peak_gpu_bytes,
            summary: done.summary,
        };
        write_record(project, &record)?;
        progress(&format!(
            "{n}: done in {seconds:.1} s, peak host memory {}{}",
            record.peak_host_bytes.map_or("n/a".into(), mib),
            record.peak_gpu_bytes.map(|b| format!(", GPU {}", mib(b))).unwrap_or_default()
        ));
        for w in &done.notes {
            progress(&format!("    {w}"));
        }
        upstream.push((stage, record.outputs_fingerprint.clone()));
        outcomes.push(StageOutcome { stage, status: "ran".into(), seconds });
    }
    let report = project.join("report.html");
    Ok(ProcessSummary { project: project.clone(), report: report.is_file().then_some(report), stages: outcomes })
}

fn mib(b: u64) -> String {
    format!("{:.0} MiB", b as f64 / 1048576.0)
}

fn validate(o: &ProcessOptions) -> Result<(), ProcessError> {
    let bad = |key: &str, reason: String| Err(ProcessError::Option { key: key.into(), reason });
    if !o.flight.is_dir() {
        return bad("FLIGHT_DIR", format!("{} is not a folder", o.flight.display()));
    }
    let (f, p) = (o.flight.canonicalize().ok(), o.project.canonicalize().ok());
    if let (Some(f), Some(p)) = (&f, &p) {
        if p.starts_with(f) || f.starts_with(p) {
            return bad("--out", "the project folder and the flight folder must not contain one another".into());
        }
    }
    if let Some(t) = o.time_budget_s {
        if !(t > 0.0 && t.is_finite()) {
            return bad("--time-budget", format!("{t}: must be a positive number of seconds"));
        }
    }
    if let Some(g) = o.gsd {
        if !(g > 0.0 && g.is_finite()) {
            return bad("--gsd", format!("{g}: must be a positive cell size"));
        }
    }
    if o.cloud_rays == 0 || o.cloud_rays > crate::cli::export::MAX_EXPORT_RAYS {
        return bad("--cloud-rays", format!("{}: must be 1..={}", o.cloud_rays, crate::cli::export::MAX_EXPORT_RAYS));
    }
    if let Some((_, p)) = &o.poses {
        if !p.exists() {
            return bad("--poses", format!("{} does not exist", p.display()));
        }
    }
    Ok(())
}

/// The ground control file's path and content hash (None without one): an edited `gcp_list.txt` imports again.
fn gcp_fingerprint(o: &ProcessOptions) -> Option<(String, String)> {
    let path = o.ground_control.path(&o.flight)?;
    // A missing file given by name fails in the import, which names it.
    let bytes = std::fs::read(&path).ok()?;
    Some((path.display().to_string(), super::stage::sha256_hex(&bytes)))
}

/// What a stage depends on: its options and its upstream stages' outputs.
fn stage_inputs(o: &ProcessOptions, stage: Stage, flight_fp: &str, upstream: &[(Stage, String)]) -> String {
    let opts = match stage {
        Stage::Import => json!({
            "flight": flight_fp, "panel_reflectance": o.panel_reflectance, "irradiance": o.irradiance,
            "units": o.units, "reference_band": o.reference_band, "crs": o.crs.as_ref().map(|c| c.key()),
            "gcp": gcp_fingerprint(o),
        }),
        Stage::Poses => json!({"poses": o.poses.as_ref().map(|(f, p)| (f, p.display().to_string()))}),
        Stage::Check => json!({}),
        Stage::Train => json!({
            "model": o.model, "hardware": o.hardware, "time_budget_s": o.time_budget_s, "max_steps": o.max_steps,
            "seed": o.seed, "images_only": o.images_only,
        }),
        Stage::Eval => json!({}),
        Stage::Cloud => json!({"rays": o.cloud_rays}),
        Stage::Survey => json!({
            "gsd": o.gsd, "indices": o.indices.iter().map(|i| i.name()).collect::<Vec<_>>(), "fill": o.fill,
        }),
        Stage::Terrain => {
            let p = crate::products::terrain::SmrfParams::default();
            json!({"smrf": [p.cell, p.slope, p.window, p.threshold, p.scalar], "trees": "defaults"})
        }
        Stage::Report => json!({}),
    };
    let deps: Vec<&(Stage, String)> = upstream
        .iter()
        .filter(|(s, _)| match stage {
            Stage::Eval | Stage::Cloud | Stage::Survey => *s <= Stage::Train,
            _ => true,
        })
        .collect();
    let v = json!({"stage": stage, "options": opts, "upstream": deps, "msnerf": env!("CARGO_PKG_VERSION")});
    super::stage::sha256_hex(v.to_string().as_bytes())
}

fn describe(stage: Stage, o: &ProcessOptions) -> String {
    match stage {
        Stage::Import => format!("raw rig files of {} -> calibrated, registered dataset", o.flight.display()),
        Stage::Poses => match &o.poses {
            Some((f, p)) => format!("poses and sparse points from {f:?} ({})", p.display()),
            None => "COLMAP: poses and sparse points, geo-registered to the GPS".into(),
        },
        Stage::Check => "dataset check".into(),
        Stage::Train => "training (hardware profile, depth supervision from the sparse points)".into(),
        Stage::Eval => "held-out views: PSNR and SSIM per band".into(),
        Stage::Cloud => "multispectral point cloud".into(),
        Stage::Survey => "DSM, true orthomosaic and index rasters".into(),
        Stage::Terrain => "DTM (SMRF), canopy height model and trees".into(),
        Stage::Report => "processing report".into(),
    }
}

/// What one stage produced.
pub(super) struct Done {
    /// Files and folders the stage owns, relative to the project.
    pub(super) outputs: Vec<PathBuf>,
    pub(super) summary: serde_json::Value,
    pub(super) notes: Vec<String>,
    pub(super) peak_gpu_bytes: Option<u64>,
}

pub(super) fn done(outputs: Vec<PathBuf>, summary: serde_json::Value, notes: Vec<String>) -> Done {
    Done { outputs, summary, notes, peak_gpu_bytes: None }
}

fn run_stage(o: &ProcessOptions, stage: Stage, inputs: &str, progress: Progress) -> Result<Done, ProcessError> {
    let fail = ProcessError::stage(stage);
    match stage {
        Stage::Import => super::stages::import(o).map_err(|e| fail(&e)),
        Stage::Poses => super::stages::poses(o).map_err(|e| fail(&e)),
        Stage::Check => super::stages::check(o),
        Stage::Train => super::stages::train(o, inputs, progress),
        Stage::Eval => super::stages::eval(o),
        Stage::Cloud => super::stages::cloud(o),
        Stage::Survey => super::stages::survey(o, progress),
        Stage::Terrain => super::stages::terrain(o),
        Stage::Report => super::report::write_report(&o.project, &o.flight)
            .map(|path| done(vec![path.strip_prefix(&o.project).unwrap_or(&path).to_path_buf()], json!({}), vec![])),
    }
    .map(|mut d| {
        d.outputs.retain(|p| o.project.join(p).exists());
        d
    })
}

pub(super) mod paths {
    use super::*;
    pub fn dataset() -> PathBuf {
        rel("dataset")
    }
    pub fn run() -> PathBuf {
        rel("run")
    }
    pub fn products() -> PathBuf {
        rel("products")
    }
}

pub(super) type StageDone = Done;
pub(super) fn gpu_peak(ctx: &Context) -> u64 {
    ctx.with_ledger(|l| l.total_peak())
}
/// A GPU stage's result with its peak device memory; a stage whose context recorded validation-layer messages
/// fails with them (the layer is on where `MSNERF_VALIDATION` or `MSNERF_REQUIRE_VALIDATION` asks for it).
pub(super) fn with_gpu(mut d: Done, ctx: &Context) -> Result<Done, ProcessError> {
    let msgs = ctx.validation_messages();
    if !msgs.is_empty() {
        return Err(ProcessError::Stage {
            stage: "gpu".into(),
            reason: format!("{} Vulkan validation message(s): {}", msgs.len(), msgs.join("; ")),
        });
    }
    d.peak_gpu_bytes = Some(gpu_peak(ctx));
    Ok(d)
}
