//! Implausible camera centres (issue 20, item 4): a camera moved far from the others is refused by name, or left
//! out with `drop_outliers`; `dataset check` says which; training with `--drop-outliers` leaves it out of the run.

use crate::common;
use common::TempDir;
use msnerf::data::{load_dataset, LoadOptions, Split};
use serde_json::Value;

/// `ci-small` with frame `victim` moved to `x`.
fn dataset_with_moved_camera(dir: &std::path::Path, victim: usize, x: f64) -> String {
    common::simulate_ci_small(dir);
    let p = dir.join("transforms.json");
    let mut t: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    let f = &mut t["frames"][victim];
    f["transform_matrix"][0][3] = serde_json::json!(x);
    let name = f["file_path"].as_str().unwrap().to_string();
    std::fs::write(&p, serde_json::to_string_pretty(&t).unwrap()).unwrap();
    name
}

#[test]
fn clean_datasets_have_no_outliers() {
    let t = TempDir::new("outl-clean");
    let data = t.path().join("data");
    common::simulate_ci_small(&data);
    let ds = load_dataset(&data, &LoadOptions::default()).unwrap();
    assert!(ds.dropped_outliers.is_empty());
    let campus = TempDir::new("outl-campus");
    let scene = msnerf::sim::SceneDesc::load("campus").unwrap();
    let opts = msnerf::sim::SimOptions { width: Some(32), height: Some(24), ..Default::default() };
    msnerf::sim::simulate(&scene, &opts, &campus.path().join("data")).unwrap();
    load_dataset(&campus.path().join("data"), &LoadOptions::default())
        .expect("the campus flight has no outlying camera");
}

#[test]
fn a_far_camera_is_refused_by_name_or_dropped_and_listed() {
    for x in [1e300, 5e4] {
        let t = TempDir::new("outl-far");
        let dir = t.path().join("data");
        let name = dataset_with_moved_camera(&dir, 3, x);
        let e = load_dataset(&dir, &LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains(&name) && e.contains("--drop-outliers") && e.contains("median"), "{e}");

        let ds = load_dataset(&dir, &LoadOptions { drop_outliers: true, ..Default::default() }).unwrap();
        assert_eq!(ds.dropped_outliers, vec![name.clone()]);
        let f = ds.frames.iter().find(|f| f.name == name).unwrap();
        assert_eq!(f.split, Split::Unused);
        // The normalisation ignores it: the others still fill the unit cube.
        let pt = ds.pose_transform();
        assert!(pt.scale > 1e-3, "scale {}", pt.scale);

        let rep = msnerf::data::check_dataset(&dir, 1 << 30);
        assert!(!rep.is_ok() && rep.to_string().contains(&name));
        let opts = LoadOptions { drop_outliers: true, ..Default::default() };
        let rep = msnerf::data::check::check_dataset_with(&dir, 1 << 30, &opts);
        assert!(rep.is_ok(), "{rep}");
        assert!(rep.to_string().contains(&format!("left out: {name}")), "{rep}");
    }
}

#[test]
fn training_with_drop_outliers_leaves_the_frame_out() {
    let t = TempDir::new("outl-train");
    let data = t.path().join("data");
    let name = dataset_with_moved_camera(&data, 5, 1e6);
    let g = common::gpu();
    let mut model = msnerf::nerf::config::ModelConfig::resolve("tiny").unwrap();
    model.trainer.max_steps = 2;
    let run = t.path().join("run");
    let e = msnerf::nerf::trainer::train(&g, &common::train_options(&data, &run, model.clone(), 256))
        .unwrap_err()
        .to_string();
    assert!(e.contains(&name), "{e}");
    model.sampling.drop_outlier_cameras = true;
    let s = msnerf::nerf::trainer::train(&g, &common::train_options(&data, &run, model, 256)).unwrap();
    assert_eq!(s.steps, 2);
    let info: Value = serde_json::from_str(&std::fs::read_to_string(run.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(info["dropped_outliers"][0], name.as_str());
}
