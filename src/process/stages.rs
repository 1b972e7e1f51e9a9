//! The stages of `msnerf process`, each the library call of its per-step command with the defaults a survey
//! wants, returning the files it owns and a summary for the report.

use std::path::{Path, PathBuf};

use serde_json::json;

use super::error::ProcessError;
use super::run::{done, paths, with_gpu, ProcessOptions, Progress, StageDone, CPU_TIME_BUDGET_S};
use super::stage::Stage;
use crate::gpu::Context;
use crate::nerf::config::ModelConfig;
use crate::nerf::run::LoadedRun;

/// Import: the raw flight -> `dataset/`; `transforms.import.json` keeps the import's own poses (GPS priors), from
/// which the poses stage starts again on a rerun.
pub(super) fn import(o: &ProcessOptions) -> Result<StageDone, crate::rig::RigError> {
    let out = o.project.join(paths::dataset());
    let opts = crate::rig::ImportOptions {
        panel_reflectance: o.panel_reflectance.clone(),
        irradiance: o.irradiance,
        units: o.units,
        reference_band: o.reference_band.clone(),
        crs: o.crs.clone(),
        ground_control: o.ground_control.clone(),
        overwrite: true,
        threads: o.threads,
        progress: true,
        ..crate::rig::ImportOptions::new(&o.flight, &out)
    };
    let s = crate::rig::import_rig(&opts)?;
    let t = out.join("transforms.json");
    std::fs::copy(&t, out.join("transforms.import.json")).map_err(crate::rig::RigError::io(&t))?;
    let d = paths::dataset();
    let mut notes: Vec<String> = s.warnings.iter().map(|w| format!("warning: {w}")).collect();
    notes.extend(s.skipped.iter().map(|k| format!("skipped {}: {}", k.what, k.reason)));
    notes
        .insert(0, format!("{} captures, bands {}; irradiance from {}", s.captures, s.bands.join(", "), s.calibration));
    Ok(done(
        vec![
            d.join("images"),
            d.join("sfm_images"),
            d.join("import_report.json"),
            d.join("transforms.import.json"),
            d.join("panel_report.json"),
        ],
        serde_json::to_value(&s).expect("the summary serialises"),
        notes,
    ))
}

/// Poses: COLMAP on the imported dataset (geo-registered to the GPS), or the poses of another tool.
pub(super) fn poses(o: &ProcessOptions) -> Result<StageDone, Box<dyn std::error::Error>> {
    let ds = o.project.join(paths::dataset());
    // Start from the import's transforms.json: a rerun never builds on an earlier run's poses.
    let t = ds.join("transforms.json");
    crate::util::atomic::write_bytes(&t, &std::fs::read(ds.join("transforms.import.json"))?)?;
    for stale in ["sparse_points.json", "transforms.before-poses.json", "transforms.before-sfm.json"] {
        let _ = std::fs::remove_file(ds.join(stale));
    }
    let d = paths::dataset();
    let outputs = vec![d.join("transforms.json"), d.join("sparse_points.json")];
    match &o.poses {
        Some((format, path)) => {
            let model = format.read(path, o.crs.as_ref())?;
            let r = crate::poses::apply_poses(&model, path, &ds)?;
            let notes = vec![format!(
                "{} of {} frames posed from {}; {} sparse points",
                r.registered, r.frames, r.source, r.points
            )];
            Ok(done(outputs, serde_json::to_value(&r)?, notes))
        }
        None => {
            let ws = ds.join("colmap");
            if ws.exists() {
                std::fs::remove_dir_all(&ws)?;
            }
            let mut so = crate::sfm::SfmOptions::new(&ds);
            so.threads = o.threads.max(1);
            // COLMAP on the mean of the stretched bands: the sensor's noise is independent between bands, the scene's
            // texture is not, so the mean has √B times less noise; the most textured single band counts noise as
            // texture (docs/results/flight.md measures both).
            so.band = crate::sfm::images::BandChoice::Pan;
            // Each frame matched with its nearest neighbours by GPS, as OpenDroneMap does on a flight with GPS
            // (`spatial` falls back to sequential matching without fixes).
            let t: serde_json::Value = serde_json::from_slice(&std::fs::read(&t)?)?;
            let frames = t["frames"].as_array().map_or(&[][..], |v| v.as_slice());
            let with_gps = frames.iter().filter(|f| f["gps"].is_object()).count();
            if with_gps * 10 >= frames.len() * 9 && frames.len() > SPATIAL_NEIGHBOURS {
                so.matcher = crate::sfm::run::Matcher::Spatial;
                so.overlap = SPATIAL_NEIGHBOURS;
            }
            if let Some(c) = &o.crs {
                so.crs = Some(c.clone());
            }
            let r = crate::sfm::run_sfm(&so)?;
            let mut notes = vec![format!(
                "registered {} of {} frames; {} sparse points; mean reprojection error {}",
                r.registered,
                r.frames,
                r.points,
                r.mean_reprojection_error_px.map_or("n/a".into(), |e| format!("{e:.3} px"))
            )];
            if let Some(g) = &r.georef {
                notes.push(format!("geo-registered in {}:", r.crs.as_deref().unwrap_or("the dataset's CRS")));
                notes.extend(g.describe().into_iter().map(|l| format!("  {l}")));
            }
            notes.extend(r.unregistered.iter().map(|f| format!("not registered: {f}")));
            Ok(done(
                outputs.into_iter().chain([d.join("colmap/sfm_report.json")]).collect(),
                serde_json::to_value(&r)?,
                notes,
            ))
        }
    }
}

/// Neighbours each frame is matched with by GPS position in the poses stage.
pub const SPATIAL_NEIGHBOURS: usize = 12;

/// Check: `dataset check`; a problem stops the run (the record is not written, so the stage runs again).
pub(super) fn check(o: &ProcessOptions) -> Result<StageDone, ProcessError> {
    let ds = o.project.join(paths::dataset());
    let rep = crate::data::check_dataset(&ds, 8 << 30);
    let path = o.project.join("check.json");
    crate::util::atomic::write_bytes(&path, rep.to_json().as_bytes())
        .map_err(|e| ProcessError::Output { path: path.clone(), reason: e.to_string() })?;
    if !rep.is_ok() {
        return Err(ProcessError::Stage {
            stage: Stage::Check.name().into(),
            reason: format!("{} problem(s): {}", rep.errors.len(), rep.errors.join("; ")),
        });
    }
    let notes = rep.warnings.iter().map(|w| format!("warning: {w}")).collect();
    Ok(done(vec![PathBuf::from("check.json")], serde_json::to_value(&rep).expect("json"), notes))
}

/// The model profile `process` trains: `--model`, or for `auto` Table 1's on a GPU and the demo's on a CPU device.
fn model_for(o: &ProcessOptions, ctx: &Context) -> Result<ModelConfig, ProcessError> {
    let name = match o.model.as_str() {
        "auto" if ctx.caps().is_cpu => "demo",
        "auto" => "multispectral-nerf",
        m => m,
    };
    let mut m = ModelConfig::resolve(name)
        .map_err(|e| ProcessError::Option { key: "--model".into(), reason: e.to_string() })?;
    if o.images_only {
        m.loss.depth = None;
    }
    Ok(m)
}

/// Train: the hardware's profile, depth supervision from the sparse points, resumed from the run's checkpoint when
/// the stage was interrupted with the same inputs.
pub(super) fn train(o: &ProcessOptions, inputs: &str, progress: Progress) -> Result<StageDone, ProcessError> {
    let fail = ProcessError::stage(Stage::Train);
    let ctx = Context::new(&o.device).map_err(|e| fail(&e))?;
    let run = o.project.join(paths::run());
    let marker = run.join("process-inputs.txt");
    let resume = run.join("checkpoints/latest.json").is_file()
        && std::fs::read_to_string(&marker).is_ok_and(|m| m.trim() == inputs);
    if run.exists() && !resume {
        std::fs::remove_dir_all(&run).map_err(ProcessError::io(&run))?;
    }
    let data = o.project.join(paths::dataset());
    let base = model_for(o, &ctx)?;
    let ds = crate::nerf::trainer::load_run_dataset(&data, None, &base.sampling).map_err(|e| fail(&e))?;
    let fitted = crate::plan::train::fit_training(&ctx, &o.hardware, base, &ds, |mut m| {
        if let Some(s) = o.max_steps {
            m.trainer.max_steps = s;
        }
        if let Some(s) = o.seed {
            m.trainer.seed = s;
        }
        Ok(m)
    })
    .map_err(|e| fail(&e))?;
    progress(&format!("    {}", fitted.describe()));
    let budget = o.time_budget_s.or(ctx.caps().is_cpu.then_some(CPU_TIME_BUDGET_S));
    if o.time_budget_s.is_none() && budget.is_some() {
        progress(&format!(
            "    a CPU device: training limited to {CPU_TIME_BUDGET_S:.0} s (--time-budget to change; a GPU trains the \
             profile's steps)"
        ));
    }
    if resume {
        progress("    resuming from the run's checkpoint");
    }
    drop(ds);
    std::fs::create_dir_all(&run).map_err(ProcessError::io(&run))?;
    let opts = crate::nerf::trainer::TrainOptions {
        data,
        model: fitted.model.clone(),
        out: run.clone(),
        resume,
        time_budget_s: budget,
        host_budget_bytes: fitted.host_budget_bytes,
        resample_every: fitted.resample_every.unwrap_or(500),
        eval_pixels: 4096,
        progress: true,
        stop: o.stop.clone(),
        bands: None,
    };
    crate::util::atomic::write_bytes(&marker, inputs.as_bytes()).map_err(|e| fail(&e))?;
    let s = crate::nerf::trainer::train(&ctx, &opts).map_err(|e| fail(&e))?;
    if s.stopped_early.is_some() && o.stop.as_ref().is_some_and(|f| f.load(std::sync::atomic::Ordering::Relaxed)) {
        return Err(fail(&"interrupted: the checkpoint is kept, and a rerun resumes from it"));
    }
    if let Some(n) = s.notes.iter().find(|n| n.starts_with(crate::nerf::trainer::NOTHING_LEARNT)) {
        return Err(fail(&format!("{n}; the products would show nothing of the flight (see {})", run.display())));
    }
    let mut notes = vec![
        format!(
            "{} steps in {:.0} s; held-out PSNR (sampled pixels) best {}",
            s.steps,
            s.elapsed_s,
            s.best_eval_psnr.map_or("n/a".into(), |v| format!("{v:.2} dB"))
        ),
        format!("depth supervision: {}", s.depth_supervision),
    ];
    notes.extend(s.notes.iter().map(|n| format!("warning: {n}")));
    let r = paths::run();
    let summary = json!({
        "model": fitted.model.name, "hardware": fitted.plan.profile, "steps": s.steps, "seconds": s.elapsed_s,
        "rays_per_s": s.rays_per_s, "best_sampled_eval_psnr": s.best_eval_psnr, "eval_history": s.eval_history,
        "depth_supervision": s.depth_supervision, "device": s.device, "planned_vram_bytes": fitted.plan.vram.total_bytes,
        "planned_host_bytes": fitted.plan.process_host_bytes(ctx.caps().is_cpu),
        "planned_cache_bytes": fitted.plan.host.peak_bytes, "host_budget_bytes": fitted.host_budget_bytes,
        "peak_gpu_bytes": s.peak_gpu_bytes,
        "peak_cache_bytes": s.peak_cache_bytes, "stopped_early": s.stopped_early, "notes": s.notes,
    });
    with_gpu(
        done(
            vec![
                r.join("config.yaml"),
                r.join("dataset.json"),
                r.join("dataparser_transforms.json"),
                r.join("checkpoints"),
            ],
            summary,
            notes,
        ),
        &ctx,
    )
}

/// Eval: every held-out view, PSNR and SSIM per band (`run/eval.json`).
pub(super) fn eval(o: &ProcessOptions) -> Result<StageDone, ProcessError> {
    let fail = ProcessError::stage(Stage::Eval);
    let ctx = Context::new(&o.device).map_err(|e| fail(&e))?;
    let mut run = LoadedRun::load(&ctx, &o.project.join(paths::run())).map_err(|e| fail(&e))?;
    let rep =
        crate::nerf::evaluate::evaluate(&mut run, crate::data::Split::Eval, None, None, false).map_err(|e| fail(&e))?;
    let path = o.project.join(paths::run()).join("eval.json");
    rep.write(&path).map_err(|e| fail(&e))?;
    let notes = vec![rep
        .bands
        .iter()
        .map(|b| format!("{} {:.2} dB / SSIM {:.3}", b.name, b.psnr, b.ssim))
        .collect::<Vec<_>>()
        .join(", ")];
    with_gpu(done(vec![paths::run().join("eval.json")], serde_json::to_value(&rep).expect("json"), notes), &ctx)
}

/// The host bytes of decoded training images an export may hold: the training's cache budget from the planner (the
/// train stage's record), so every stage of the flight stays within one host budget; the export's own default when
/// the record lacks it.
fn image_budget(o: &ProcessOptions) -> u64 {
    super::stage::read_record(&o.project, Stage::Train)
        .ok()
        .flatten()
        .and_then(|r| r.summary["host_budget_bytes"].as_u64())
        .unwrap_or(crate::nerf::export::REFINE_IMAGE_BUDGET)
}

/// Cloud: the careful export with the photometric refinement and the default filters, as LAS in the dataset's CRS.
pub(super) fn cloud(o: &ProcessOptions) -> Result<StageDone, ProcessError> {
    let fail = ProcessError::stage(Stage::Cloud);
    let ctx = Context::new(&o.device).map_err(|e| fail(&e))?;
    let mut run = LoadedRun::load(&ctx, &o.project.join(paths::run())).map_err(|e| fail(&e))?;
    let budget = image_budget(o);
    let opts =
        crate::nerf::export::ExportOptions { rays: o.cloud_rays, image_budget_bytes: budget, ..Default::default() };
    let (raw, stats) = crate::nerf::export::export_points_with_stats(&mut run, &opts).map_err(|e| fail(&e))?;
    let cloud = crate::products::cloud::CloudFilter::default().apply(raw).map_err(|e| fail(&e))?;
    let dir = o.project.join(paths::products());
    std::fs::create_dir_all(&dir).map_err(ProcessError::io(&dir))?;
    let out = dir.join("cloud.las");
    crate::products::cloud::write_cloud(&cloud, &out, run.ds.crs.as_ref()).map_err(|e| fail(&e))?;
    let mut notes = vec![crate::products::cloud::summary(&stats, opts.min_accumulation, cloud.len())];
    notes.extend(crate::products::cloud::unsupported_note(&stats));
    let summary = json!({
        "points": cloud.len(), "rays": stats.rays, "below_accumulation": stats.below_accumulation,
        "outside_box": stats.outside_box, "spread": stats.spread, "inconsistent": stats.inconsistent, "kept": stats.kept,
        "unsupported": stats.unsupported, "refine": stats.refine.as_ref().map(|r| json!({"points": r.points, "moved": r.moved, "kept": r.kept})),
        "image_budget_bytes": budget,
        "crs": run.ds.crs.as_ref().map(|c| c.key()),
    });
    with_gpu(done(vec![paths::products().join("cloud.las")], summary, notes), &ctx)
}

/// The flight's ground sampling distance: per training camera, its height above the sparse points' median height
/// over its focal length; the median over cameras. None without sparse points.
pub fn flight_gsd(ds: &crate::data::Dataset) -> Option<f64> {
    let path = ds.sparse_points_path.as_ref()?;
    let pts = crate::data::sparse_points::read_sparse_points(ds, path).ok()?;
    if pts.is_empty() {
        return None;
    }
    let ground = crate::util::stats::median(&pts.iter().map(|p| p.xyz[2]).collect::<Vec<_>>());
    let g: Vec<f64> = ds
        .split_indices(crate::data::Split::Train)
        .iter()
        .map(|&f| (ds.frames[f].c2w[2][3] - ground) / ds.frames[f].camera.fx)
        .filter(|g| *g > 0.0)
        .collect();
    (!g.is_empty()).then(|| crate::util::stats::median(&g))
}

/// Survey: DSM, true ortho and index rasters on one grid over what the cameras saw, at the flight's GSD.
pub(super) fn survey(o: &ProcessOptions, progress: Progress) -> Result<StageDone, ProcessError> {
    use crate::nerf::survey::{seen_bounds, SurveyGrid, SurveyOptions};
    use crate::nerf::survey_products::{export_survey, SurveyOutputs};
    let fail = ProcessError::stage(Stage::Survey);
    let ctx = Context::new(&o.device).map_err(|e| fail(&e))?;
    let mut run = LoadedRun::load(&ctx, &o.project.join(paths::run())).map_err(|e| fail(&e))?;
    let gsd = match o.gsd {
        Some(g) => g,
        None => flight_gsd(&run.ds)
            .ok_or_else(|| fail(&"the flight's ground sampling distance is unknown (no sparse points): give --gsd"))?,
    };
    let bounds = seen_bounds(&mut run).map_err(|e| fail(&e))?;
    let grid = SurveyGrid::covering(bounds, gsd, crate::nerf::survey::MAX_SURVEY_CELLS).map_err(|e| fail(&e))?;
    progress(&format!("    grid {} x {} cells of {gsd:.3} (world units)", grid.width, grid.height));
    let dir = o.project.join(paths::products());
    std::fs::create_dir_all(&dir).map_err(ProcessError::io(&dir))?;
    let outputs = SurveyOutputs {
        dsm: Some(dir.join("dsm.tif")),
        ortho: Some(dir.join("ortho.tif")),
        indices: o.indices.clone(),
    };
    let opts = SurveyOptions { fill: o.fill, image_budget_bytes: image_budget(o), ..SurveyOptions::default() };
    let rep = export_survey(&mut run, &grid, &opts, &outputs, |_| {}).map_err(|e| fail(&e))?;
    let s = &rep.stats;
    if s.valid == 0 {
        return Err(fail(&format!(
            "no cell of the {} x {} grid has a height ({} without a surface, {} inconsistent across views): the field \
             holds no ground to map",
            grid.width, grid.height, s.no_surface, s.inconsistent
        )));
    }
    let notes = vec![
        format!(
            "{} cells: {} with a height ({:.1} %), {} refined photometrically, {} without photometric support ({} of \
             them not confirmed by a second reference)",
            s.cells,
            s.valid,
            100.0 * s.valid as f64 / s.cells.max(1) as f64,
            s.refined,
            s.unsupported,
            s.unconfirmed
        ),
        s.quality_line(),
    ];
    let files: Vec<PathBuf> = rep.files.iter().map(|f| f.strip_prefix(&o.project).unwrap_or(f).to_path_buf()).collect();
    let summary = json!({
        "gsd": gsd, "grid": {"width": grid.width, "height": grid.height, "origin": grid.origin}, "stats": s,
        "notes": rep.notes, "image_budget_bytes": opts.image_budget_bytes,
    });
    with_gpu(done(files, summary, notes), &ctx)
}

/// Terrain: the DTM by SMRF from the survey's DSM (its measured and interpolated cells), the canopy height model
/// and the trees with the ortho's band means and NDVI per crown, all on the DSM's grid (`export dtm|chm|trees`).
pub(super) fn terrain(o: &ProcessOptions) -> Result<StageDone, ProcessError> {
    use crate::products::canopy::{make_chm, make_dtm, make_trees};
    use crate::products::terrain::SmrfParams;
    use crate::products::trees::{CrownParams, TopParams};
    let fail = ProcessError::stage(Stage::Terrain);
    let dir = o.project.join(paths::products());
    let (dsm, ortho) = (dir.join("dsm.tif"), dir.join("ortho.tif"));
    let (dtm, chm, trees) = (dir.join("dtm.tif"), dir.join("chm.tif"), dir.join("trees.geojson"));
    let d = make_dtm(&dsm, &dtm, &SmrfParams::default(), false).map_err(|e| fail(&e))?;
    let c = make_chm(&dsm, &dtm, &chm).map_err(|e| fail(&e))?;
    let ortho = ortho.is_file().then_some(ortho.as_path());
    let t = make_trees(&chm, Some(&dtm), ortho, &trees, &TopParams::default(), &CrownParams::default())
        .map_err(|e| fail(&e))?;
    let mut notes = vec![d.line(), c.line(), t.line()];
    notes.extend(t.notes.iter().cloned());
    let heights: Vec<f64> = t.trees.iter().map(|t| (t.height * 100.0).round() / 100.0).collect();
    let summary = json!({
        "dtm": {"dsm_cells": d.dsm_cells, "candidates": d.candidates, "ground": d.ground, "cells": d.dtm_cells},
        "chm": {"cells": c.cells, "above_2m": c.above_2m, "max": c.max},
        "trees": {"count": t.trees.len(), "not_vegetation": t.not_vegetation, "heights": heights},
    });
    let files = d.files.iter().chain(&c.files).chain(&t.files);
    let files: Vec<PathBuf> = files.map(|f| f.strip_prefix(&o.project).unwrap_or(f).to_path_buf()).collect();
    Ok(done(files, summary, notes))
}

/// A file of the project, for the report.
pub fn project_file(project: &Path, rel: &str) -> PathBuf {
    project.join(rel)
}
