//! The exported point cloud lands on the scene's surfaces: train the `tiny` model on the simulated `ci-small` scene
//! (as tests/train_e2e.rs does), `msnerf export pointcloud --normals`, and compare with the simulator's ground-truth
//! surface points (`ground_truth.ply`): the median distance to them, and the normals' shape (~35 s on 2 cores).

mod common;

use common::{gpu, TempDir};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::trainer::train;
use msnerf::output::pointcloud::read_ply;
use msnerf::output::{compare_clouds, CompareOptions};
use msnerf::sim::{simulate, SceneDesc, SimOptions};

#[test]
fn exported_points_lie_near_the_ground_truth_surfaces_with_unit_normals() {
    let tmp = TempDir::new("export_surface");
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    simulate(&SceneDesc::load("ci-small").expect("scene"), &SimOptions::default(), &data).expect("simulate");
    {
        let g = gpu();
        let mut model = ModelConfig::resolve("tiny").expect("tiny");
        model.trainer.max_steps = 200;
        model.trainer.steps_per_eval = 1000;
        model.trainer.steps_per_save = 1000;
        train(&g, &common::train_options(&data, &run, model, 256)).expect("train");
    }
    let ply = tmp.path().join("cloud.ply");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
        .args(["export", "pointcloud", run.to_str().expect("utf-8"), "--out", ply.to_str().expect("utf-8")])
        .args(["--rays", "20000", "--normals"])
        .output()
        .expect("run msnerf");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    let cloud = read_ply(&ply).expect("exported PLY");
    let normals = cloud.normals.clone().expect("--normals writes nx ny nz");
    assert!(cloud.len() > 5000, "{} points", cloud.len());

    // Distance to the ground truth, pred -> nearest ground-truth surface sample (`compare-cloud`'s accuracy).
    let reference = read_ply(&data.join("ground_truth.ply")).expect("ground truth");
    let report = compare_clouds(&cloud, &reference, &CompareOptions::default()).expect("compare");
    let median = report.accuracy.median;
    eprintln!("accuracy median {median:.3} m, mean {:.3} m, {} points", report.accuracy.mean, cloud.len());
    assert!(median < MAX_MEDIAN_M, "median distance to the ground-truth surface {median:.3} m");

    // Normals: unit vectors (a vanishing gradient would be written as zero).
    let unit = normals.iter().filter(|n| ((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-4);
    assert!(unit.count() as f64 >= 0.99 * normals.len() as f64, "normals are unit vectors");
    // On the flat ground (world z = 20 in ci-small, its world_offset; roof, crowns and trunks start 1.5 m higher)
    // the normals are only reported: after 200 steps the field is a fog above the ground (3.7 % of the points lie
    // within 0.5 m of z = 20, signed elevation error +4 m) and its gradient there is not the ground's orientation
    // (MEASURED: median n_z 0.075, 14 % above 0.5; 0.16 after 300 steps; 0.13 with 48 views; averaging the gradient
    // over 0.5-2 m does not help). With more training they turn up: 48 views and 800 steps (133 s, too slow here)
    // give a median distance of 1.1 m and ground median n_z 0.43. The gradient chain itself is checked against its
    // twin and finite differences in tests/nerf_normals.rs.
    let mut nz: Vec<f32> =
        cloud.positions.iter().zip(&normals).filter(|(p, _)| (p[2] - 20.0).abs() < 0.5).map(|(_, n)| n[2]).collect();
    assert!(nz.len() > 100, "{} ground points", nz.len());
    nz.sort_by(f32::total_cmp);
    let up = nz.iter().filter(|&&z| z > 0.5).count() as f64 / nz.len() as f64;
    eprintln!("ground: {} points, median n_z {:.3}, {:.1} % with n_z > 0.5", nz.len(), nz[nz.len() / 2], 100.0 * up);
}

/// MEASURED on lavapipe (2 cores): median distance 4.65 m after 200 steps (120 steps: 569 m, the points still at the
/// far plane; 300 steps: 5.1 m). 7 m keeps a 50 % margin and still fails a cloud that is not on the scene.
const MAX_MEDIAN_M: f64 = 7.0;
