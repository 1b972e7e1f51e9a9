//! A real sweep on lavapipe: a tiny simulated scene, the `tiny` profile, two cells of about a second each. Every
//! cell gets a result with per-band held-out scores at each wall-clock point, the step-time breakdown and peak
//! memory; a second run skips finished cells and redoes an unfinished one; the CLI writes every output from them.

use crate::common;
use common::gpu;
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use msnerf::sweep::run::{cell_dir, cell_id};
use msnerf::sweep::{run_sweep, Grid, SweepOptions};
use std::path::Path;

fn dataset(dir: &Path) {
    let scene = SceneDesc::load("ci-small").expect("built-in scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

const GRID: &str =
    "name: resume\nmodel: tiny\nbudget: {time_s: 1.2}\neval_at_s: [0.6]\neval_views: 1\neval_pixels: 256\n\
                    axes:\n  bands: [[0, 1, 2, 3, 4, 5], [5, 0]]\n";

#[test]
fn a_sweep_measures_every_cell_and_resumes_without_redoing_finished_ones() {
    let g = gpu();
    let root = common::TempDir::new("sweep_resume");
    let data = root.path().join("data");
    dataset(&data);
    let grid_path = root.path().join("grid.yaml");
    std::fs::write(&grid_path, GRID).unwrap();
    let grid = Grid::load(&grid_path).expect("grid");
    let out = root.path().join("out");
    let opts = SweepOptions { data: data.clone(), out: out.clone(), host_budget_bytes: 1 << 30, progress: false };

    let first = run_sweep(&g, &grid, &opts).expect("sweep");
    assert_eq!(first.trained.len(), 2, "{:?}", first.failed);
    assert!(first.skipped.is_empty() && first.failed.is_empty());
    for (r, nb) in first.results.iter().zip([6, 2]) {
        assert_eq!(r.band_names.len(), nb, "{}", r.id);
        assert_eq!(r.points.len(), 2, "one point at 0.6 s and one at the end of the budget");
        assert_eq!(r.points[0].target_s, 0.6);
        assert_eq!(r.points[1].target_s, 1.2);
        for p in &r.points {
            assert!(p.elapsed_s >= p.target_s, "a segment ends once its time is reached: {p:?}");
            assert!(p.psnr.is_finite() && p.psnr > 3.0, "{p:?}");
            assert_eq!(p.bands.len(), nb);
            assert!(p.bands.iter().all(|b| b.psnr.is_finite() && b.ssim.is_finite()));
        }
        assert!(
            r.points[1].step > r.points[0].step && r.steps == r.points[1].step,
            "training went on between points: {:?}",
            r.points
        );
        assert!(r.mean_step_ms > 0.0 && r.gpu_ms_per_step > 0.0);
        assert!(r.kernels.iter().any(|k| k.name.starts_with("mlp") && k.ms_per_step > 0.0), "{:?}", r.kernels);
        assert!(r.peak_gpu_bytes > 1 << 20 && r.peak_cache_bytes > 0 && r.parameters > 0);
        assert!(r.trainer_best_eval_psnr.is_some());
        assert!(r.stopped.contains("time budget"), "{}", r.stopped);
        assert!(cell_dir(&out, &r.id).join("result.json").is_file());
        assert!(cell_dir(&out, &r.id).join("checkpoints/latest.msnp").is_file(), "the cell folder is a run folder");
    }
    assert_eq!(first.results[1].band_names, ["nir", "blue"], "band subsets keep the order asked for");

    // Rerun: both cells are done and skipped, their results untouched.
    let before = std::fs::read(cell_dir(&out, &first.results[0].id).join("result.json")).unwrap();
    let again = run_sweep(&g, &grid, &opts).expect("rerun");
    assert_eq!(again.skipped.len(), 2);
    assert!(again.trained.is_empty());
    let ids = |o: &msnerf::sweep::SweepOutcome| o.results.iter().map(|r| (r.id.clone(), r.steps)).collect::<Vec<_>>();
    assert_eq!(ids(&again), ids(&first), "the finished results are read back, in grid order");

    // An unfinished cell (stopped before its result was written) is redone from scratch; the other is not.
    let id1 = cell_id(&grid, &grid.cells[1]);
    std::fs::remove_file(cell_dir(&out, &id1).join("result.json")).unwrap();
    std::fs::write(cell_dir(&out, &id1).join("stale.txt"), "left from the interrupted run").unwrap();
    let third = run_sweep(&g, &grid, &opts).expect("resume");
    assert_eq!(third.skipped, vec![first.results[0].id.clone()]);
    assert_eq!(third.trained, vec![id1.clone()]);
    assert!(!cell_dir(&out, &id1).join("stale.txt").exists(), "an unfinished cell starts from an empty folder");
    assert_eq!(std::fs::read(cell_dir(&out, &first.results[0].id).join("result.json")).unwrap(), before);
    drop(g);

    // The CLI on the same folder: nothing to train, every output written.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
        .args(["sweep", "--grid"])
        .arg(&grid_path)
        .arg("--data")
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .arg("--report")
        .arg(root.path().join("page.md"))
        .output()
        .expect("run msnerf");
    let text = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("0 trained now, 2 done before"), "{text}");
    for f in [
        "cells.csv",
        "points.csv",
        "kernels.csv",
        "sweep.json",
        "report.md",
        "plots/psnr_vs_time.png",
        "plots/psnr_vs_time.svg",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let page = std::fs::read_to_string(root.path().join("page.md")).unwrap();
    assert!(page.contains("(page/psnr_vs_time.svg)"), "the extra report links its own plot folder");
    assert!(root.path().join("page/memory_vs_psnr.png").is_file());
    assert_eq!(std::fs::read_to_string(out.join("cells.csv")).unwrap().lines().count(), 3);
}

#[test]
fn a_step_budget_ends_cells_by_steps_and_bad_band_subsets_are_rejected_before_training() {
    let g = gpu();
    let root = common::TempDir::new("sweep_steps");
    let data = root.path().join("data");
    dataset(&data);
    // Cell 1 asks for band 9 of a 6-band dataset: rejected before anything trains, naming the cell.
    let bad =
        Grid::parse("name: s\nmodel: tiny\nbudget: {steps: 3}\naxes:\n  bands: [[0], [9]]\n", Path::new(""), "s.yaml")
            .expect("grid");
    let opts =
        SweepOptions { data: data.clone(), out: root.path().join("bad"), host_budget_bytes: 1 << 30, progress: false };
    let e = run_sweep(&g, &bad, &opts).expect_err("band 9 does not exist").to_string();
    assert!(e.contains("cell 1") && e.contains("band index 9"), "{e}");
    assert!(!root.path().join("bad/cells").exists(), "nothing trained");

    let grid = Grid::parse("name: s\nmodel: tiny\nbudget: {steps: 3}\neval_views: 1\n", Path::new(""), "s.yaml")
        .expect("grid");
    let opts = SweepOptions { data, out: root.path().join("out"), host_budget_bytes: 1 << 30, progress: false };
    let o = run_sweep(&g, &grid, &opts).expect("sweep");
    let r = &o.results[0];
    assert_eq!(r.steps, 3);
    assert_eq!(r.points.len(), 1);
    assert!(r.stopped.contains("step budget"), "{}", r.stopped);
}
