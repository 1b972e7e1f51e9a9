//! `msnerf demo [--out DIR]`: the whole job on the built-in simulated campus scene: simulate it, train with a demo
//! profile on a time budget, evaluate held-out views, render CIR and NDVI previews, export the multispectral point
//! cloud, compare it with the scene's ground truth, and print a summary with where every output is.
//! Sized to finish in under 5 minutes on 2 CPU cores with lavapipe.
//!
//! As on a real flight, where the poses come from structure from motion and bring its sparse points with them, the
//! simulated dataset carries SfM points (noise 0.1 m) and training uses them for DS-NeRF depth supervision
//! (docs/geometry.md); `--images-only` trains on the images alone, for comparison.

use super::Cli;
use crate::data::Split;
use crate::gpu::Context;
use crate::nerf::config::ModelConfig;
use crate::nerf::export::{export_points, ExportOptions};
use crate::nerf::run::LoadedRun;
use crate::nerf::trainer::{train, TrainOptions};
use crate::output::compare::{compare_clouds, CompareOptions};
use crate::output::pointcloud::read_ply;
use crate::output::raster::indices::VegetationIndex;
use crate::products::cloud::{write_cloud, CloudFilter};
use crate::products::views::{write_contact_sheet, write_view, ViewOptions};
use crate::sim::sparse::SparseOptions;
use crate::sim::{simulate, SceneDesc, SimOptions};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Output folder (replaced if it holds a previous demo)
    #[arg(long, default_value = "demo-output")]
    pub out: PathBuf,
    /// Seconds of training
    #[arg(long, value_parser = super::positive_f64, default_value_t = 90.0)]
    pub time_budget: f64,
    /// Held-out views to evaluate (the demo keeps this small; `msnerf eval` evaluates them all)
    #[arg(long, default_value_t = 6)]
    pub eval_views: usize,
    /// Scene: built-in name or YAML file
    #[arg(long, default_value = "campus")]
    pub scene: String,
    /// Model profile
    #[arg(long, default_value = "demo")]
    pub model: String,
    /// Train on the images alone: no simulated SfM points, no depth supervision
    #[arg(long)]
    pub images_only: bool,
}

/// The simulated SfM points of the demo: about as many as structure from motion finds on such a flight, with
/// 0.1 m of position noise, each seen by at least 3 views.
const DEMO_SPARSE: SparseOptions = SparseOptions { count: 20_000, noise_m: 0.1, min_views: 3 };

const MARKER: &str = "msnerf-demo.json";

fn prepare_out(out: &Path) -> anyhow::Result<()> {
    if out.exists() {
        let empty = std::fs::read_dir(out)?.next().is_none();
        anyhow::ensure!(
            empty || out.join(MARKER).is_file(),
            "{} exists and is not a previous demo: choose another --out",
            out.display()
        );
        if !empty {
            std::fs::remove_dir_all(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
        }
    }
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    crate::util::atomic::write_bytes(&out.join(MARKER), b"{\"demo\": true}\n")?;
    Ok(())
}

pub fn run(cli: &Cli, a: &DemoArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    prepare_out(&a.out)?;
    let data = a.out.join("data");
    let run_dir = a.out.join("run");
    let renders = a.out.join("renders");
    let cloud_path = a.out.join("cloud.ply");

    println!("[1/6] simulating scene `{}`", a.scene);
    let scene = SceneDesc::load(&a.scene)?;
    let sim_opts = SimOptions { sparse_points: (!a.images_only).then_some(DEMO_SPARSE), ..SimOptions::default() };
    let sim = simulate(&scene, &sim_opts, &data)?;
    println!("      {sim}");

    let supervision = if a.images_only { "images only" } else { "images + DS-NeRF depth from the SfM points" };
    println!("[2/6] training `{}` for {:.0} s ({supervision})", a.model, a.time_budget);
    let ctx = Context::new(&cli.context_desc())?;
    // Depth supervision comes from the profile (`loss.depth`, on where the dataset has sparse points); the demo's
    // dataset has none with --images-only, and the profile's is switched off too, so the run is images alone.
    let mut model = ModelConfig::resolve(&a.model)?;
    if a.images_only {
        model.loss.depth = None;
    }
    let opts = TrainOptions {
        data: data.clone(),
        model,
        out: run_dir.clone(),
        resume: false,
        time_budget_s: Some(a.time_budget),
        host_budget_bytes: 2 << 30,
        resample_every: 500,
        eval_pixels: 4096,
        progress: true,
        stop: None,
        bands: None,
    };
    let ts = train(&ctx, &opts)?;

    println!("[3/6] evaluating held-out views");
    let mut run = LoadedRun::load(&ctx, &run_dir)?;
    let has_depth = run.ds.frames.iter().all(|f| f.depth.is_some());
    let report = crate::nerf::evaluate::evaluate(&mut run, Split::Eval, Some(a.eval_views), None, has_depth)?;
    report.write(&run_dir.join("eval.json"))?;

    println!("[4/6] rendering CIR and NDVI previews");
    std::fs::create_dir_all(&renders)?;
    let vo = ViewOptions { indices: vec![VegetationIndex::Ndvi, VegetationIndex::Ndre720], ..Default::default() };
    let frames = run.ds.split_indices(Split::Eval);
    let mut tiles = Vec::new();
    for &f in frames.iter().take(2) {
        tiles.extend(write_view(&mut run, f, &renders, &vo)?.tiles);
    }
    write_contact_sheet(&tiles, tiles.len() / frames.len().clamp(1, 2), &renders)?;

    println!("[5/6] exporting the multispectral point cloud");
    // The same export and filters as `msnerf export pointcloud` (their defaults), at 100,000 rays.
    let raw = export_points(&mut run, &ExportOptions { rays: 100_000, ..Default::default() })?;
    let cloud = CloudFilter::default().apply(raw)?;
    write_cloud(&cloud, &cloud_path, run.ds.crs.as_ref())?;
    write_cloud(&cloud, &cloud_path.with_extension("las"), run.ds.crs.as_ref())?;

    println!("[6/6] comparing with the ground-truth cloud");
    let reference = read_ply(&data.join("ground_truth.ply"))?;
    let cmp = compare_clouds(&cloud, &reference, &CompareOptions { threshold: 0.5, band_tolerance_nm: 25.0 })?;
    crate::util::atomic::write_bytes(&a.out.join("compare.json"), cmp.to_json().as_bytes())?;

    let peak = ctx.with_ledger(|l| l.total_peak());
    println!();
    println!("msnerf demo on {} ({}, {supervision})", a.scene, ctx.caps().name);
    print!("{}", report.table());
    println!(
        "training: {} steps in {:.0} s, {:.0} rays/s; held-out PSNR {} -> {}",
        ts.steps,
        ts.elapsed_s,
        ts.rays_per_s,
        ts.first_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or("n/a".into()),
        ts.best_eval_psnr.map(|v| format!("{v:.2} dB")).unwrap_or("n/a".into())
    );
    println!(
        "point cloud: {} points; accuracy (to ground truth) mean {:.3} m, median {:.3} m; completeness mean {:.3} m; F-score@0.5 m {:.3}",
        cloud.len(),
        cmp.accuracy.mean,
        cmp.accuracy.median,
        cmp.completeness.mean,
        cmp.f_score
    );
    let v = &cmp.standard;
    println!(
        "paper's accuracy standard (RMSE planar <= {} m, vertical <= {} m): planar {:.2} m, vertical {:.2} m: {}",
        v.planar.limit,
        v.vertical.limit,
        v.planar.rmse,
        v.vertical.rmse,
        if v.pass { "met" } else { "not met" }
    );
    println!(
        "peak GPU memory {:.1} MiB, peak image cache {:.1} MiB, total time {:.0} s",
        peak as f64 / 1048576.0,
        ts.peak_cache_bytes as f64 / 1048576.0,
        t0.elapsed().as_secs_f64()
    );
    println!(
        "outputs: dataset {}, run {}, renders {}, cloud {} (+ .las), comparison {}",
        data.display(),
        run_dir.display(),
        renders.display(),
        cloud_path.display(),
        a.out.join("compare.json").display()
    );
    Ok(())
}
