//! Training on a subset of a dataset's bands (sweep axis `bands`, `msnerf train --bands`): the data layer reads
//! only the selected bands, in the order asked for; bad selections are errors naming `bands`; a run trained on a
//! subset records it and loads back with it. Also the time-budgeted summary: the model it stops with is evaluated,
//! and the step time comes with its per-kernel breakdown.

use crate::common;
use common::gpu;
use msnerf::data::{load_dataset, LoadOptions};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::run::LoadedRun;
use msnerf::nerf::trainer::{train, TrainOptions};
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use std::path::Path;

fn dataset(dir: &Path) {
    let scene = SceneDesc::load("ci-small").expect("built-in scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

#[test]
fn a_band_selection_reads_exactly_those_bands_in_that_order() {
    let root = common::TempDir::new("sweep_bands");
    let data = root.path().join("data");
    dataset(&data);
    let full = load_dataset(&data, &LoadOptions::default()).expect("dataset");
    assert_eq!(full.n_bands(), 6);
    let mut sub = full.clone();
    sub.select_bands(&[5, 0, 2]).expect("select");
    assert_eq!(sub.n_bands(), 3);
    let names: Vec<&str> = sub.bands.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, [full.bands[5].name.as_str(), full.bands[0].name.as_str(), full.bands[2].name.as_str()]);
    assert_eq!(sub.file_bands().len(), 6, "the files still hold six");
    assert_eq!(sub.image_bytes() * 2, full.image_bytes(), "the cache budget counts the selected bands only");
    for frame in [0, 7] {
        let a = full.read_frame(frame).expect("full frame");
        let b = sub.read_frame(frame).expect("subset frame");
        assert_eq!((b.width, b.height, b.bands), (a.width, a.height, 3));
        assert_eq!(b.mask, a.mask);
        for (k, src) in [5usize, 0, 2].into_iter().enumerate() {
            assert_eq!(b.band_f32(k), a.band_f32(src), "frame {frame}: band {k} is file band {src}");
            assert_eq!(b.scaling[k], a.scaling[src]);
        }
    }
    // Selecting again picks from the file's bands, not from the previous selection.
    sub.select_bands(&[1]).expect("reselect");
    assert_eq!(sub.bands[0].name, full.bands[1].name);
    assert_eq!(sub.read_frame(3).unwrap().band_f32(0), full.read_frame(3).unwrap().band_f32(1));
}

#[test]
fn bad_band_selections_are_errors_naming_bands() {
    let root = common::TempDir::new("sweep_bands_bad");
    let data = root.path().join("data");
    dataset(&data);
    let mut ds = load_dataset(&data, &LoadOptions::default()).expect("dataset");
    for (sel, what) in
        [(vec![], "empty"), (vec![0, 6], "band index 6 is out of range"), (vec![2, 1, 2], "selected twice")]
    {
        let e = ds.select_bands(&sel).expect_err("rejected").to_string();
        assert!(e.contains("transforms.json") && e.contains("bands") && e.contains(what), "{sel:?}: {e}");
    }
    assert_eq!(ds.n_bands(), 6, "a rejected selection changes nothing");
}

#[test]
fn a_run_on_a_band_subset_trains_records_it_and_loads_back_with_it() {
    let g = gpu();
    let root = common::TempDir::new("sweep_bands_train");
    let data = root.path().join("data");
    dataset(&data);
    let run = root.path().join("run");
    let mut model = ModelConfig::resolve("tiny").unwrap();
    model.trainer.max_steps = 100_000;
    model.trainer.steps_per_eval = 100_000;
    let opts = TrainOptions {
        data: data.clone(),
        model,
        out: run.clone(),
        resume: false,
        time_budget_s: Some(1.0),
        host_budget_bytes: 1 << 30,
        resample_every: 500,
        eval_pixels: 512,
        progress: false,
        stop: None,
        bands: Some(vec![3, 4, 5]),
    };
    let s = train(&g, &opts).expect("train");
    assert!(s.stopped_early.as_deref().is_some_and(|w| w.contains("time budget")));
    // The model the budget stopped at is evaluated, so the best held-out PSNR includes where training ended.
    assert_eq!(s.eval_history.last().map(|e| e.0), Some(s.steps), "{:?}", s.eval_history);
    assert!(s.best_eval_psnr.is_some() && s.best_eval_step.is_some());
    assert!(s.mean_step_ms > 0.0 && s.gpu_ms_per_step > 0.0);
    assert!(!s.kernels.is_empty() && s.kernels.windows(2).all(|w| w[0].total_ms >= w[1].total_ms), "largest first");
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(info["band_indices"], serde_json::json!([3, 4, 5]));
    assert_eq!(info["bands"].as_array().map(|b| b.len()), Some(3));
    let loaded = LoadedRun::load(&g, &run).expect("loads back");
    assert_eq!(loaded.ds.n_bands(), 3);
    assert_eq!(loaded.pipe.model.bands, 3);
}
