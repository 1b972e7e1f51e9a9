//! Cloud comparison on analytic cases and the `msnerf compare-cloud` command.

mod output_support;

use msnerf::output::compare::{compare_clouds, CompareOptions, DistanceStats};
use msnerf::output::image::{band, ms600pro_bands};
use msnerf::output::pointcloud::{subsample, write_las, write_ply, LasOptions, PlyOptions, PointCloud};
use output_support::scratch;

/// A 20 x 20 grid with 1 m spacing at UTM-like coordinates, z = 10, and six bands.
fn grid() -> PointCloud {
    let pos: Vec<[f64; 3]> =
        (0..400).map(|i| [500000.0 + (i % 20) as f64, 4000000.0 + (i / 20) as f64, 10.0]).collect();
    let values: Vec<f32> = (0..400 * 6).map(|k| 0.1 + 0.01 * (k % 37) as f32).collect();
    PointCloud::new(pos, ms600pro_bands(), values).unwrap()
}

#[test]
fn shifted_copy_gives_the_shift() {
    let reference = grid();
    let mut pred = reference.clone();
    // dx = 0.25, dy = 0 .. planar 0.25; dz = -0.125; |d| = sqrt(0.078125).
    for p in &mut pred.positions {
        p[0] += 0.25;
        p[2] -= 0.125;
    }
    // Reflectance: +0.02 on every band of pred.
    for v in &mut pred.values {
        *v += 0.02;
    }
    let r = compare_clouds(&pred, &reference, &CompareOptions { threshold: 0.5, band_tolerance_nm: 25.0 }).unwrap();
    let d = (0.25f64 * 0.25 + 0.125 * 0.125).sqrt();
    for s in [&r.accuracy, &r.completeness] {
        assert!((s.mean - d).abs() < 1e-9 && (s.median - d).abs() < 1e-9 && (s.rmse - d).abs() < 1e-9, "{s:?}");
    }
    assert_eq!((r.precision, r.recall, r.f_score), (1.0, 1.0, 1.0));
    assert!((r.position.mean_planar - 0.25).abs() < 1e-9);
    assert!((r.position.mean_elevation - 0.125).abs() < 1e-12);
    assert!((r.position.mean_signed_dz + 0.125).abs() < 1e-12);
    assert!((r.position.mean_euclidean - d).abs() < 1e-9);
    assert_eq!(r.bands.len(), 6);
    for b in &r.bands {
        assert_eq!(b.pairs, 400);
        assert!((b.mae - 0.02).abs() < 1e-6 && (b.rmse - 0.02).abs() < 1e-6 && (b.bias - 0.02).abs() < 1e-6, "{b:?}");
        assert_eq!(b.pred_center_nm, b.ref_center_nm);
    }
    // A threshold below the shift: nothing matches.
    let r = compare_clouds(&pred, &reference, &CompareOptions { threshold: 0.2, band_tolerance_nm: 25.0 }).unwrap();
    assert_eq!((r.precision, r.recall, r.f_score), (0.0, 0.0, 0.0));
    assert!(r.bands.iter().all(|b| b.pairs == 0));
    let j: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
    assert!(j["bands"][0]["mae"].is_null(), "no pairs: null, not NaN");
}

#[test]
fn subsampled_prediction_has_the_expected_completeness() {
    let reference = grid();
    // Every other column of the grid: half the reference points are 1 m from the prediction.
    let keep: Vec<usize> = (0..400).filter(|i| i % 2 == 0).collect();
    let pred = reference.select(&keep);
    let r = compare_clouds(&pred, &reference, &CompareOptions { threshold: 0.1, band_tolerance_nm: 25.0 }).unwrap();
    assert_eq!(r.accuracy.mean, 0.0);
    assert_eq!(r.precision, 1.0);
    assert_eq!(r.recall, 0.5);
    assert!((r.f_score - 2.0 * 0.5 / 1.5).abs() < 1e-12);
    assert!((r.completeness.mean - 0.5).abs() < 1e-12);
    assert_eq!(r.completeness.median, 0.5);
    assert!((r.completeness.rmse - 0.5f64.sqrt()).abs() < 1e-12);
    assert_eq!(r.completeness.max, 1.0);
    // A random quarter (deterministic).
    let (q, _) = subsample(&reference, 100, 7).unwrap();
    let r = compare_clouds(&q, &reference, &CompareOptions::default()).unwrap();
    assert_eq!(r.recall, 0.25);
    assert_eq!(r.accuracy.max, 0.0);
}

#[test]
fn bands_pair_by_wavelength_and_missing_bands_are_noted() {
    let reference = grid();
    // Pred has only NIR 842 and Red 668 (MicaSense-like centres), in another order.
    let bands = vec![band("NIR", Some(842.0), None), band("Red", Some(668.0), None)];
    let values: Vec<f32> =
        (0..400).flat_map(|i| [reference.point_values(i)[5] + 0.1, reference.point_values(i)[2]]).collect();
    let pred = PointCloud::new(reference.positions.clone(), bands, values).unwrap();
    let r = compare_clouds(&pred, &reference, &CompareOptions::default()).unwrap();
    assert_eq!(r.bands.len(), 2);
    assert_eq!((r.bands[0].ref_band.as_str(), r.bands[1].ref_band.as_str()), ("NIR", "Red"));
    assert!((r.bands[0].bias - 0.1).abs() < 1e-6);
    assert_eq!(r.bands[1].mae, 0.0);

    let bare = PointCloud::new(reference.positions.clone(), vec![], vec![]).unwrap();
    let r = compare_clouds(&bare, &reference, &CompareOptions::default()).unwrap();
    assert!(r.bands.is_empty() && r.band_note.as_deref().unwrap().contains("pred has 0 bands"));
    assert!(compare_clouds(&bare, &reference, &CompareOptions { threshold: 0.0, band_tolerance_nm: 25.0 }).is_err());
    let empty = PointCloud::new(vec![], vec![], vec![]).unwrap();
    assert!(compare_clouds(&empty, &reference, &CompareOptions::default()).is_err());
}

#[test]
fn distance_stats_median_of_even_count() {
    let s = DistanceStats::of(&[4.0, 1.0, 3.0, 2.0]);
    assert_eq!((s.mean, s.median, s.max, s.count), (2.5, 2.5, 4.0, 4));
    assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-12);
}

#[test]
fn compare_cloud_command_reads_ply_and_las() {
    let dir = scratch("compare_cli");
    let reference = grid();
    let mut pred = reference.clone();
    for p in &mut pred.positions {
        p[1] += 0.0625;
    }
    let (a, b) = (dir.join("pred.ply"), dir.join("ref.las"));
    write_ply(&a, &pred, &PlyOptions::default()).unwrap();
    write_las(&b, &reference, &LasOptions { all_bands_as_extra_bytes: true, ..Default::default() }).unwrap();
    let exe = env!("CARGO_BIN_EXE_msnerf");
    let out = std::process::Command::new(exe)
        .args(["compare-cloud", "--pred"])
        .arg(&a)
        .arg("--ref")
        .arg(&b)
        .args(["--threshold", "0.1", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["pred_points"], 400);
    assert!((j["accuracy"]["mean"].as_f64().unwrap() - 0.0625).abs() < 1e-9);
    assert!((j["position"]["mean_planar"].as_f64().unwrap() - 0.0625).abs() < 1e-9);
    assert_eq!(j["f_score"], 1.0);
    assert_eq!(j["bands"].as_array().unwrap().len(), 6);
    assert!(j["bands"][0]["mae"].as_f64().unwrap() < 1e-7);

    let out = std::process::Command::new(exe)
        .args(["compare-cloud", "--pred"])
        .arg(&a)
        .arg("--ref")
        .arg(&b)
        .output()
        .unwrap();
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("accuracy (pred->ref)") && table.contains("F-score"), "{table}");

    let missing = dir.join("nope.ply");
    let out = std::process::Command::new(exe)
        .args(["compare-cloud", "--pred"])
        .arg(&missing)
        .arg("--ref")
        .arg(&b)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope.ply"), "{err}");
}
