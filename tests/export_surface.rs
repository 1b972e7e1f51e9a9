//! Geometry on the simulated `ci-textured` scene (ci-small with albedo texture), issue 18: train the `tiny` model
//! for a fixed number of steps, then
//! - the rendered median depth on the flat ground (pixels whose true surface point lies at ground height) is
//!   compared with the simulator's depth maps: its median signed bias, in pixel footprints, must stay small;
//! - `msnerf export pointcloud` (the careful default: exact median, spread filter, multi-view consistency) lies
//!   closer to the simulator's ground-truth surface than the `--legacy` export, carries the confidence scalar
//!   fields, and its normals are unit vectors;
//! - `msnerf eval --depth` writes the depth section of its report.
//!
//! (~60 s on 2 cores.)

mod common;

use common::{gpu, TempDir};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::trainer::train;
use msnerf::output::pointcloud::read_ply;
use msnerf::output::{compare_clouds, CompareOptions};
use msnerf::sim::{simulate, SceneDesc, SimOptions};

#[test]
fn geometry_sits_on_the_true_surface() {
    let tmp = TempDir::new("export_surface");
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    simulate(&SceneDesc::load("ci-textured").expect("scene"), &SimOptions::default(), &data).expect("simulate");
    {
        let g = gpu();
        let mut model = ModelConfig::resolve("tiny").expect("tiny");
        model.trainer.max_steps = STEPS;
        model.trainer.steps_per_eval = 1000;
        model.trainer.steps_per_save = 1000;
        train(&g, &common::train_options(&data, &run, model, 256)).expect("train");
    }

    // 1. Depth bias on flat ground.
    let (bias, pixels) = common::ground_bias_footprints(&run);
    eprintln!("flat ground: {pixels} pixels, median bias {bias:+.3} footprints (+ = above the ground)");
    assert!(pixels > 5000, "{pixels} ground pixels");
    assert!(bias.abs() < MAX_GROUND_BIAS_FOOTPRINTS, "median depth bias on flat ground {bias:+.3} footprints");

    // 2. The careful export against the legacy one.
    let reference = read_ply(&data.join("ground_truth.ply")).expect("ground truth");
    let run_s = run.to_str().expect("utf-8");
    let mut medians = Vec::new();
    for (name, extra) in [("careful", &["--normals"][..]), ("legacy", &["--legacy"][..])] {
        let ply = tmp.path().join(format!("{name}.ply"));
        let text = common::msnerf(
            env!("CARGO_BIN_EXE_msnerf"),
            &[&["export", "pointcloud", run_s, "--out", ply.to_str().unwrap(), "--rays", "20000"], extra].concat(),
        );
        let cloud = read_ply(&ply).expect("exported PLY");
        let r = compare_clouds(&cloud, &reference, &CompareOptions::default()).expect("compare");
        eprintln!(
            "{name}: {} points, accuracy median {:.3} m, mean {:.3} m; {}",
            cloud.len(),
            r.accuracy.median,
            r.accuracy.mean,
            text.trim()
        );
        assert!(cloud.len() > 2000, "{name}: {} points", cloud.len());
        medians.push(r.accuracy.median);
        if name == "careful" {
            for a in ["accumulation", "depth_spread", "agreeing_views", "checked_views"] {
                assert!(cloud.attribute(a).is_some(), "careful export carries `{a}`");
            }
            let agree = &cloud.attribute("agreeing_views").expect("agreeing_views").values;
            assert!(agree.iter().all(|&v| v >= 2.0), "every kept point has at least 2 agreeing views");
            let normals = cloud.normals.clone().expect("--normals writes nx ny nz");
            let unit = normals.iter().filter(|n| ((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-4);
            assert!(unit.count() as f64 >= 0.99 * normals.len() as f64, "normals are unit vectors");
        }
    }
    assert!(medians[0] < MAX_MEDIAN_M, "careful export: median distance {:.3} m", medians[0]);
    assert!(medians[0] < medians[1], "careful export {:.3} m is closer than legacy {:.3} m", medians[0], medians[1]);

    // 3. eval --depth writes the depth section.
    let report = tmp.path().join("eval.json");
    common::msnerf(env!("CARGO_BIN_EXE_msnerf"), &["eval", run_s, "--depth", "--output", report.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    let d = &v["depth"]["overall"];
    assert!(d["pixels"].as_u64().unwrap_or(0) > 1000, "{d}");
    assert!(d["median_abs_error"].as_f64().is_some_and(|x| x.is_finite()), "{d}");

    // 4. A depth map of the wrong size is an error naming the file and the frame.
    for e in std::fs::read_dir(data.join("depth")).expect("depth dir") {
        let p = e.expect("entry").path();
        let f = std::fs::File::create(&p).expect("create");
        tiff::encoder::TiffEncoder::new(f)
            .expect("tiff")
            .write_image::<tiff::encoder::colortype::Gray32Float>(4, 4, &[1.0f32; 16])
            .expect("write");
    }
    // `eval --depth` must fail: its error message.
    let eval_depth_error = || {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
            .args(["eval", run_s, "--depth"])
            .output()
            .expect("run");
        assert!(!out.status.success(), "eval --depth succeeded");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = eval_depth_error();
    assert!(err.contains("depth/") && err.contains("4x4"), "{err}");

    // 5. `--depth` on a dataset without depth maps is an error naming the frame.
    let tf = data.join("transforms.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&tf).expect("read")).expect("json");
    for f in t["frames"].as_array_mut().expect("frames") {
        f.as_object_mut().expect("frame").remove("depth_file_path");
    }
    std::fs::write(&tf, serde_json::to_string(&t).expect("json")).expect("write");
    let err = eval_depth_error();
    assert!(err.contains("depth_file_path") && err.contains("frame `"), "{err}");
}

/// Training steps of the test.
const STEPS: u64 = 600;
/// MEASURED (2026-11-25, docs/geometry.md "CI test"): +0.22 and +0.40 footprints in two lavapipe runs; on an
/// NVIDIA H100 +0.11 to +0.91 over 10 runs (median +0.34): float atomics make every run differ. The same
/// scene with uniform materials (what the simulator made before issue 18) gives +10.5 footprints over all pixels.
const MAX_GROUND_BIAS_FOOTPRINTS: f64 = 1.25;
/// MEASURED: careful export 0.80 m (legacy 1.03 m) from the ground-truth samples; to their local plane (compare's
/// default since 2026-11-25) 0.80 m (legacy 1.09 m). The pixel footprint is ~0.45 m. Before issue 18: 7 m allowed.
const MAX_MEDIAN_M: f64 = 1.2;
