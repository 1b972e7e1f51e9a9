//! Shared helpers for tests/sim_*.rs: temp folders, small scenes as YAML, and simulate-then-load.
#![allow(dead_code)]

use std::path::Path;

use msnerf::data::{load_dataset, Dataset, LoadOptions, Raster};
use msnerf::sim::{simulate, SceneDesc, SimOptions};

pub use crate::common::TempDir;

pub fn scene(yaml: &str) -> SceneDesc {
    SceneDesc::from_yaml(yaml, "test.yaml").unwrap_or_else(|e| panic!("{e}"))
}

/// Simulates into a fresh temp folder and loads the result.
pub fn run(desc: &SceneDesc, opts: &SimOptions) -> (TempDir, Dataset) {
    let t = TempDir::new("run");
    let out = t.path().join("ds");
    simulate(desc, opts, &out).unwrap_or_else(|e| panic!("{e}"));
    let ds = load_dataset(&out, &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    (t, ds)
}

pub fn run_yaml(yaml: &str) -> (TempDir, Dataset) {
    run(&scene(yaml), &SimOptions::default())
}

pub fn frame(ds: &Dataset, i: usize) -> Raster {
    ds.read_frame(i).unwrap_or_else(|e| panic!("{e}"))
}

/// Frames in the order written (the loader sorts by name; names are view_00000, ... so the order is the same).
pub fn nframes(ds: &Dataset) -> usize {
    ds.frames.len()
}

/// Every file under `dir` (relative path, bytes), sorted.
pub fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    fn walk(base: &Path, d: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.push((p.strip_prefix(base).unwrap().display().to_string(), std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut v = Vec::new();
    walk(dir, dir, &mut v);
    v.sort();
    v
}

/// Materials block with flat and spectral materials used by the small test scenes.
pub const MATERIALS: &str = r#"
materials:
  panel: {flat: 0.4}
  dark: {flat: 0.1}
  roof: {flat: 0.3}
  wall: {flat: 0.25}
  leaves:
    vegetation: true
    spectrum: [[400, 0.03], [500, 0.05], [550, 0.09], [660, 0.04], [700, 0.10], [740, 0.35], [800, 0.46], [900, 0.47]]
  bark: {flat: 0.12}
"#;

/// A nadir camera `h` metres above the origin, `w` x `hh` pixels, over a flat `panel` ground, plus `extra` YAML.
pub fn panel_scene(w: u32, hh: u32, extra: &str) -> String {
    format!(
        "name: panel\nimage: {{width: {w}, height: {hh}}}\n{MATERIALS}\nground: {{material: panel, extent: 1000}}\n\
cameras:\n  - poses:\n      - {{position: [0, 0, 50], look_at: [0, 0, 0], up: [0, 1, 0]}}\n      - {{position: [5, 0, 60], look_at: [5, 0, 0], up: [0, 1, 0]}}\n      - {{position: [0, 5, 40], look_at: [0, 5, 0], up: [0, 1, 0]}}\n{extra}"
    )
}
