//! nerfstudio's `applied_transform` (issue 20, item 2): `ns-process-data` writes COLMAP's poses as
//! `applied_transform * c2w` (x and y swapped, z negated). msnerf undoes it when loading, for the poses and the
//! sparse points alike, so its outputs land in COLMAP's (or the georeferenced) frame rather than a permuted one.

use crate::common;
use common::TempDir;
use msnerf::data::sparse_points::read_sparse_points;
use msnerf::data::{load_dataset, LoadOptions};
use serde_json::{json, Value};

/// nerfstudio's transform: rows (1, 0, 2) of the identity, the last negated.
const A: [[f64; 4]; 3] = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]];

fn apply(m: &Value) -> Value {
    let rows: Vec<Vec<f64>> = (0..4).map(|i| (0..4).map(|j| m[i][j].as_f64().unwrap()).collect()).collect();
    let out: Vec<Vec<f64>> = (0..4)
        .map(|i| {
            (0..4)
                .map(|j| {
                    if i == 3 {
                        rows[3][j]
                    } else {
                        (0..4).map(|k| if k < 3 { A[i][k] * rows[k][j] } else { A[i][3] * rows[3][j] }).sum()
                    }
                })
                .collect()
        })
        .collect();
    json!(out)
}

#[test]
fn applied_transform_is_undone_for_poses_and_points() {
    let t = TempDir::new("applied");
    let data = t.path().join("data");
    let scene = msnerf::sim::SceneDesc::load("ci-small").unwrap();
    let sparse = msnerf::sim::sparse::SparseOptions { count: 300, noise_m: 0.0, min_views: 2 };
    let opts = msnerf::sim::SimOptions { sparse_points: Some(sparse), ..Default::default() };
    msnerf::sim::simulate(&scene, &opts, &data).unwrap();
    let before = load_dataset(&data, &LoadOptions::default()).unwrap();
    let pts_before = read_sparse_points(&before, before.sparse_points_path.as_ref().unwrap()).unwrap();

    // Rewrite as ns-process-data would have written it.
    let tp = data.join("transforms.json");
    let mut tj: Value = serde_json::from_str(&std::fs::read_to_string(&tp).unwrap()).unwrap();
    for f in tj["frames"].as_array_mut().unwrap() {
        f["transform_matrix"] = apply(&f["transform_matrix"]);
    }
    tj["applied_transform"] = json!(A);
    std::fs::write(&tp, tj.to_string()).unwrap();
    let sp_path = before.sparse_points_path.clone().unwrap();
    let mut sp: Value = serde_json::from_str(&std::fs::read_to_string(&sp_path).unwrap()).unwrap();
    for p in sp["points"].as_array_mut().unwrap() {
        let x: Vec<f64> = (0..3).map(|i| p["xyz"][i].as_f64().unwrap()).collect();
        p["xyz"] = json!((0..3).map(|i| (0..3).map(|k| A[i][k] * x[k]).sum::<f64>() + A[i][3]).collect::<Vec<_>>());
    }
    std::fs::write(&sp_path, sp.to_string()).unwrap();

    let after = load_dataset(&data, &LoadOptions::default()).unwrap();
    assert!(after.applied_transform_undone.is_some());
    for (a, b) in after.frames.iter().zip(&before.frames) {
        for i in 0..4 {
            for j in 0..4 {
                assert!(
                    (a.c2w[i][j] - b.c2w[i][j]).abs() < 1e-9 * b.c2w[i][j].abs().max(1.0),
                    "{}: {:?} against {:?}",
                    a.name,
                    a.c2w,
                    b.c2w
                );
            }
        }
    }
    let pts_after = read_sparse_points(&after, after.sparse_points_path.as_ref().unwrap()).unwrap();
    assert_eq!(pts_after.len(), pts_before.len());
    for (a, b) in pts_after.iter().zip(&pts_before) {
        for k in 0..3 {
            assert!((a.xyz[k] - b.xyz[k]).abs() < 1e-9 * b.xyz[k].abs().max(1.0));
        }
    }

    // Not a rigid transform: the key named.
    tj["applied_transform"] = json!([[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]);
    std::fs::write(&tp, tj.to_string()).unwrap();
    let e = load_dataset(&data, &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("applied_transform") && e.contains("orthonormal"), "{e}");
}
