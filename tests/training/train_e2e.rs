//! End to end on lavapipe: simulate a small scene, train, and check that held-out PSNR rises well above its start;
//! that a stopped run resumes from its checkpoint; and that eval, render and export produce their files from the run.

use crate::common;
use common::gpu;
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::trainer::{train, TrainOptions};
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use std::path::{Path, PathBuf};

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("msnerf-e2e-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn dataset(dir: &Path) {
    let scene = SceneDesc::load("ci-small").expect("built-in scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

fn opts(data: &Path, out: &Path, steps: u64) -> TrainOptions {
    let mut model = ModelConfig::resolve("tiny").expect("tiny");
    model.trainer.max_steps = steps;
    model.trainer.steps_per_eval = 40;
    model.trainer.steps_per_save = 20;
    common::train_options(data, out, model, 2048)
}

#[test]
fn training_raises_held_out_psnr_and_resumes() {
    let g = gpu();
    let root = temp("train");
    let data = root.join("data");
    dataset(&data);
    let run = root.join("run");
    let s = train(&g, &opts(&data, &run, 120)).expect("train");
    assert_eq!(s.steps, 120);
    let first = s.first_eval_psnr.expect("evaluated at step 1");
    let best = s.best_eval_psnr.expect("evaluated");
    assert!(best > first + 8.0, "held-out PSNR must rise well above its start: {first:.2} -> {best:.2} dB");
    assert!(best > 20.0, "held-out PSNR after 120 steps: {best:.2} dB");
    // The trend is upward: the last evaluation beats the first two.
    let h = &s.eval_history;
    assert!(h.len() >= 3 && h[h.len() - 1].1 > h[0].1 && h[h.len() - 1].1 > h[1].1, "{h:?}");
    for f in [
        "config.yaml",
        "dataparser_transforms.json",
        "dataset.json",
        "metrics.jsonl",
        "summary.json",
        "checkpoints/latest.msnp",
        "checkpoints/latest.json",
    ] {
        assert!(run.join(f).is_file(), "run folder lacks {f}");
    }
    // The summary names the device, the MSNERF_* switches that were set (make test sets two) and the MLP tiling.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).expect("summary")).expect("json");
    assert!(summary["device"].as_str().is_some_and(|d| d.contains(&g.caps().name)), "{}", summary["device"]);
    let env: Vec<String> = serde_json::from_value(summary["environment"].clone()).expect("environment list");
    for (var, entry) in [
        ("MSNERF_REQUIRE_VALIDATION", "MSNERF_REQUIRE_VALIDATION=1"),
        ("MSNERF_POISON_BUFFERS", "MSNERF_POISON_BUFFERS=1"),
    ] {
        let set = std::env::var(var).is_ok_and(|v| !v.is_empty() && v != "0");
        assert_eq!(env.iter().any(|e| e == entry), set, "{var}: {env:?}");
    }
    assert!(summary["mlp_tiling"].as_str().is_some_and(|t| t.contains("shared_tiles")), "{}", summary["mlp_tiling"]);
    let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).expect("metrics");
    let lines: Vec<serde_json::Value> = metrics.lines().map(|l| serde_json::from_str(l).expect("json line")).collect();
    assert!(lines.iter().any(|l| l["rays_per_s"].as_f64().is_some_and(|v| v > 0.0)));
    assert!(lines.iter().any(|l| l["eval_psnr"].is_number()));

    // Resume: continue the same run to 160 steps; the step counter and the parameters carry over.
    let mut o = opts(&data, &run, 160);
    o.resume = true;
    let r = train(&g, &o).expect("resume");
    assert_eq!(r.steps, 160);
    assert!(r.best_eval_psnr.expect("evaluated") >= best - 0.5, "resumed training keeps what it learned");
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_run_schedule_decays_the_learning_rate_over_the_step_budget() {
    // `optimizer.schedule: run`: the field's rate goes from lr to lr_final over the run's 40 steps, not over the
    // profile's 5,000 (the tiny profile: 1e-2 -> 1e-3). Expected: lr(k) = lr^(1 - k/40) lr_final^(k/40), in f64.
    let g = gpu();
    let root = temp("schedule");
    let data = root.join("data");
    dataset(&data);
    let run = root.join("run");
    let mut o = opts(&data, &run, 40);
    use msnerf::nerf::config::LrSchedule;
    assert_eq!(o.model.optimizer.schedule, LrSchedule::Steps, "nerfstudio's step schedule by default");
    assert!(!serde_yaml::to_string(&o.model).expect("yaml").contains("schedule: "), "the default is not written");
    assert_eq!(ModelConfig::resolve("demo").expect("demo").optimizer.schedule, LrSchedule::Run);
    o.model.optimizer.schedule = LrSchedule::Run;
    let (lr0, lr1) = (o.model.optimizer.fields.lr, o.model.optimizer.fields.lr_final);
    assert!(o.model.optimizer.fields.max_steps >= 1000 && lr1 < lr0 / 5.0, "the profile's schedule is long");
    train(&g, &o).expect("train");
    let config = std::fs::read_to_string(run.join("config.yaml")).expect("config");
    assert!(config.contains("schedule: run"), "the run's config records the schedule:\n{config}");
    let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).expect("metrics");
    let mut seen = 0;
    for l in metrics.lines().map(|l| serde_json::from_str::<serde_json::Value>(l).expect("json line")) {
        let (Some(k), Some(lr)) = (l["step"].as_u64(), l["lr_fields"].as_f64()) else { continue };
        let tau = k as f64 / 40.0;
        let want = (lr0.ln() * (1.0 - tau) + lr1.ln() * tau).exp();
        assert!((lr - want).abs() <= 1e-12 * want, "step {k}: lr {lr} against {want}");
        seen += 1;
    }
    assert!(seen >= 4, "metrics.jsonl logs the learning rate:\n{metrics}");
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_stopped_run_leaves_a_checkpoint_that_resumes() {
    let g = gpu();
    let root = temp("stop");
    let data = root.join("data");
    dataset(&data);
    let run = root.join("run");
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true)); // as if Ctrl-C came at once
    let mut o = opts(&data, &run, 50);
    o.stop = Some(stop);
    let s = train(&g, &o).expect("train");
    assert_eq!(s.steps, 0);
    assert!(s.stopped_early.as_deref().is_some_and(|w| w.contains("SIGINT or SIGTERM")));
    assert!(run.join("checkpoints/latest.msnp").is_file(), "an interrupted run still saves");
    let mut o = opts(&data, &run, 10);
    o.resume = true;
    assert_eq!(train(&g, &o).expect("resume").steps, 10);
    // A time budget stops the run and says so.
    let mut o = opts(&data, &root.join("run2"), 100_000);
    o.time_budget_s = Some(0.5);
    let s = train(&g, &o).expect("time budget");
    assert!(s.steps < 100_000 && s.stopped_early.as_deref().is_some_and(|w| w.contains("time budget")));
    let _ = std::fs::remove_dir_all(&root);
}

fn msnerf(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf")).args(args).output().expect("run msnerf");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "msnerf {args:?} failed:\n{text}");
    text
}

#[test]
fn eval_render_and_export_from_a_trained_run() {
    let g = gpu();
    let root = temp("cli");
    let data = root.join("data");
    dataset(&data);
    let run = root.join("run");
    train(&g, &opts(&data, &run, 30)).expect("train");
    drop(g);
    let r = run.to_str().expect("utf-8 path");

    msnerf(&["eval", r, "--json"]);
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval.json")).expect("eval.json")).expect("json");
    for k in ["psnr", "psnr_std", "ssim", "ssim_std", "num_rays_per_sec", "fps"] {
        assert!(eval["results"][k].is_number(), "ns-eval key {k}: {}", eval["results"]);
    }
    assert!(eval["results"]["lpips"].is_null(), "LPIPS is reported as not computed, never as a number");
    assert_eq!(eval["bands"].as_array().map(|b| b.len()), Some(6));

    let renders = root.join("renders");
    msnerf(&["render", r, "--out", renders.to_str().expect("utf-8"), "--indices", "NDVI,NDRE720"]);
    let tif = std::fs::read_dir(&renders)
        .expect("renders")
        .map(|e| e.expect("entry").path())
        .find(|p| p.extension().is_some_and(|e| e == "tif") && !p.to_string_lossy().contains("_nd"))
        .expect("a view GeoTIFF");
    let info = std::process::Command::new("gdalinfo").arg("-json").arg(&tif).output().expect(
        "gdalinfo is needed to check GeoTIFFs as QGIS/GDAL users read them: run `bash tools/setup-debian.sh` (installs gdal-bin)",
    );
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("gdalinfo json");
    let bands = info["bands"].as_array().expect("bands");
    assert_eq!(bands.len(), 6, "six named bands");
    assert!(bands.iter().any(|b| b["description"].as_str().is_some_and(|d| d.contains("840"))), "{bands:?}");
    for suffix in
        ["_rgb.png", "_cir.png", "_ndvi.png", "_ndre720.png", "_ndvi.tif", "_depth.png", "_acc.png", "_error.png"]
    {
        let stem = tif.file_stem().expect("stem").to_string_lossy().into_owned();
        assert!(renders.join(format!("{stem}{suffix}")).is_file(), "missing {stem}{suffix}");
    }
    assert!(renders.join("contact_sheet.png").is_file());

    let las = root.join("cloud.las");
    let export = |extra: &[&str]| {
        let args = ["export", "pointcloud", r, "--out", las.to_str().expect("utf-8"), "--rays", "20000"];
        msnerf(&[&args[..], &["--outlier-neighbours", "0"], extra].concat())
    };
    // ci-small's materials are uniform colours: the images carry almost no texture, so the default photometric
    // refinement drops most points, and says so with the flag that keeps them.
    let text = export(&[]);
    assert!(
        text.contains("had no photometric support and were dropped") && text.contains("--keep-unsupported"),
        "{text}"
    );
    export(&["--keep-unsupported"]);
    let cloud = msnerf::output::pointcloud::read_las(&las).expect("LAS reads back");
    assert!(cloud.len() > 1000, "{} points", cloud.len());
    assert_eq!(cloud.bands.len(), 6);
    // World frame: the ci-small scene sits at UTM-sized coordinates (500000 E, 4000000 N).
    let c = cloud.positions[0];
    assert!((4.9e5..5.1e5).contains(&c[0]) && (3.9e6..4.1e6).contains(&c[1]), "{c:?}");
    let gt = data.join("ground_truth.ply");
    let cmp = msnerf(&[
        "compare-cloud",
        "--pred",
        las.to_str().expect("utf-8"),
        "--ref",
        gt.to_str().expect("utf-8"),
        "--json",
    ]);
    assert!(cmp.contains("\"accuracy\"") && cmp.contains("\"f_score\""), "{cmp}");
    msnerf(&["dataset", "check", data.to_str().expect("utf-8")]);
    let _ = std::fs::remove_dir_all(&root);
}
