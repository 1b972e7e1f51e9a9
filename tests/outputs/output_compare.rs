//! Cloud comparison on analytic cases and the `msnerf compare-cloud` command.

use crate::output_support;
use msnerf::output::compare::{
    compare_clouds, compare_clouds_with, parse_within, AccuracyOptions, AccuracyStandard, CompareOptions,
    CompareReport, DistanceModel, DistanceStats, DEFAULT_WITHIN,
};
use msnerf::output::image::{band, ms600pro_bands};
use msnerf::output::pointcloud::{subsample, write_las, write_ply, LasOptions, PlyOptions, PointCloud};
use output_support::{scratch, Rng};

/// A 20 x 20 grid with 1 m spacing at UTM-like coordinates, z = 10, and six bands.
fn grid() -> PointCloud {
    let pos: Vec<[f64; 3]> =
        (0..400).map(|i| [500000.0 + (i % 20) as f64, 4000000.0 + (i / 20) as f64, 10.0]).collect();
    let values: Vec<f32> = (0..400 * 6).map(|k| 0.1 + 0.01 * (k % 37) as f32).collect();
    PointCloud::new(pos, ms600pro_bands(), values).unwrap()
}

/// The plain nearest-point comparison (`--local-model none`), which the analytic cases below are written for.
fn nn(pred: &PointCloud, reference: &PointCloud, opts: &CompareOptions) -> msnerf::output::Result<CompareReport> {
    let acc = AccuracyOptions { model: DistanceModel::Nearest, ..AccuracyOptions::default() };
    compare_clouds_with(pred, reference, opts, &acc)
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
    let r = nn(&pred, &reference, &CompareOptions { threshold: 0.5, band_tolerance_nm: 25.0 }).unwrap();
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
    let r = nn(&pred, &reference, &CompareOptions { threshold: 0.2, band_tolerance_nm: 25.0 }).unwrap();
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
    let r = nn(&pred, &reference, &CompareOptions { threshold: 0.1, band_tolerance_nm: 25.0 }).unwrap();
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
    let r = nn(&q, &reference, &CompareOptions::default()).unwrap();
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
        .args(["--threshold", "0.1", "--json", "--local-model", "none"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["pred_points"], 400);
    assert_eq!(j["distance_model"]["kind"], "nearest");
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
    assert!(table.contains("local least-squares plane of 6 points"), "{table}");

    // By default the distance goes to the reference's local plane: a shift within the surface is no error.
    let out = std::process::Command::new(exe)
        .args(["compare-cloud", "--pred"])
        .arg(&a)
        .arg("--ref")
        .arg(&b)
        .args(["--json", "--local-k", "8"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["distance_model"]["kind"], "plane");
    assert_eq!(j["distance_model"]["k"], 8);
    assert!(j["accuracy"]["max"].as_f64().unwrap() < 1e-9, "{}", j["accuracy"]);
    assert_eq!(j["plane_fraction"], 1.0);
    for (flag, value, msg) in
        [("--local-model", "quadric", "--local-model: `quadric`"), ("--local-k", "2", "--local-k: 2")]
    {
        let out = std::process::Command::new(exe)
            .args(["compare-cloud", "--pred"])
            .arg(&a)
            .arg("--ref")
            .arg(&b)
            .args([flag, value])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(msg), "{flag} {value}: {err}");
    }

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

/// Median by sorting (mean of the two middle values for an even count).
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        (s[m - 1] + s[m]) / 2.0
    }
}

/// Brute-force nearest neighbour (plain f64, every pair): index and distance.
fn brute_nearest(q: [f64; 3], cloud: &[[f64; 3]]) -> (usize, f64) {
    let mut best = (usize::MAX, f64::INFINITY);
    for (i, p) in cloud.iter().enumerate() {
        let d = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// A seeded random cloud of `n` points in a 6 x 6 x 2 m box at UTM-like coordinates, without bands.
fn random_cloud(rng: &mut Rng, n: usize) -> PointCloud {
    let pos =
        (0..n).map(|_| [500000.0 + 6.0 * rng.f64(), 4000000.0 + 6.0 * rng.f64(), 10.0 + 2.0 * rng.f64()]).collect();
    PointCloud::new(pos, vec![], vec![]).unwrap()
}

#[test]
fn fractions_bias_and_rmse_match_a_brute_force_reference() {
    let mut rng = Rng(0x5eed_c0de_1234_5678);
    let reference = random_cloud(&mut rng, 300);
    // The prediction: a noisy, vertically biased copy of 250 of the reference points plus 50 floaters.
    let mut pos: Vec<[f64; 3]> = reference.positions[..250]
        .iter()
        .map(|p| [p[0] + 0.3 * (rng.f64() - 0.5), p[1] + 0.3 * (rng.f64() - 0.5), p[2] + 0.1 + 0.4 * (rng.f64() - 0.5)])
        .collect();
    pos.extend(random_cloud(&mut rng, 50).positions.iter().map(|p| [p[0], p[1], p[2] + 1.5]));
    let pred = PointCloud::new(pos, vec![], vec![]).unwrap();

    let within = vec![0.05, 0.1, 0.25, 0.5, 1.0];
    let standard = AccuracyStandard { planar: 0.3, vertical: 0.5 };
    let r = compare_clouds_with(
        &pred,
        &reference,
        &CompareOptions::default(),
        &AccuracyOptions { within: within.clone(), standard, model: DistanceModel::Nearest },
    )
    .unwrap();

    // Independent expectations.
    let p2r: Vec<(usize, f64)> = pred.positions.iter().map(|&q| brute_nearest(q, &reference.positions)).collect();
    let r2p: Vec<f64> = reference.positions.iter().map(|&q| brute_nearest(q, &pred.positions).1).collect();
    let (mut planar, mut dz) = (Vec::new(), Vec::new());
    for (i, &(j, _)) in p2r.iter().enumerate() {
        let (p, q) = (pred.positions[i], reference.positions[j]);
        planar.push(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt());
        dz.push(p[2] - q[2]);
    }
    let n = pred.len() as f64;
    let rmse = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let close = |a: f64, b: f64, what: &str| assert!((a - b).abs() < 1e-9, "{what}: {a} vs {b}");

    assert_eq!(r.within.len(), within.len());
    for (w, &t) in r.within.iter().zip(&within) {
        assert_eq!(w.threshold, t);
        let pf = p2r.iter().filter(|x| x.1 < t).count() as f64 / n;
        let rf = r2p.iter().filter(|&&d| d < t).count() as f64 / reference.len() as f64;
        close(w.pred_fraction, pf, "pred fraction");
        close(w.ref_fraction, rf, "ref fraction");
    }
    // Not a trivial case: at 0.25 m some predicted points are in and some out; fractions grow with t.
    assert!(r.within.windows(2).all(|w| w[0].pred_fraction <= w[1].pred_fraction));
    // The fraction at τ is the precision and the recall.
    close(r.within[1].pred_fraction, r.precision, "within(τ) = precision");
    close(r.within[1].ref_fraction, r.recall, "within(τ) = recall");

    let abs_dz: Vec<f64> = dz.iter().map(|d| d.abs()).collect();
    let p = &r.position;
    close(p.median_signed_dz, median(&dz), "median signed dz");
    close(p.mean_signed_dz, dz.iter().sum::<f64>() / n, "mean signed dz");
    close(p.median_planar, median(&planar), "median planar");
    close(p.median_elevation, median(&abs_dz), "median |dz|");
    close(p.rmse_planar, rmse(&planar), "planar RMSE");
    close(p.rmse_elevation, rmse(&dz), "elevation RMSE");
    assert!(p.median_signed_dz > 0.0, "the +0.1 m bias shows: {p:?}");

    // The verdict reports exactly those RMSEs.
    let v = &r.standard;
    close(v.planar.rmse, rmse(&planar), "verdict planar RMSE");
    close(v.vertical.rmse, rmse(&dz), "verdict vertical RMSE");
    assert_eq!((v.planar.limit, v.vertical.limit), (0.3, 0.5));
    assert_eq!(v.planar.pass, rmse(&planar) <= 0.3);
    assert_eq!(v.vertical.pass, rmse(&dz) <= 0.5);
    assert_eq!(v.pass, v.planar.pass && v.vertical.pass);

    // All of it is in the JSON and in the table.
    let j: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
    assert_eq!(j["within"].as_array().unwrap().len(), 5);
    assert_eq!(j["within"][2]["threshold"], 0.25);
    assert_eq!(j["within"][2]["pred_fraction"].as_f64().unwrap(), r.within[2].pred_fraction);
    assert_eq!(j["within"][2]["ref_fraction"].as_f64().unwrap(), r.within[2].ref_fraction);
    assert_eq!(j["position"]["median_signed_dz"].as_f64().unwrap(), p.median_signed_dz);
    assert_eq!(j["position"]["median_planar"].as_f64().unwrap(), p.median_planar);
    assert_eq!(j["position"]["median_elevation"].as_f64().unwrap(), p.median_elevation);
    assert_eq!(j["standard"]["planar"]["rmse"].as_f64().unwrap(), v.planar.rmse);
    assert_eq!(j["standard"]["vertical"]["limit"], 0.5);
    assert_eq!(j["standard"]["pass"], v.pass);
    assert!(j["standard"]["statistic"].as_str().unwrap().contains("RMSE"));
    let table = r.table();
    for needle in ["fraction within", "< 0.25", "signed dz", "RMSE", "planar", "vertical", "overall"] {
        assert!(table.contains(needle), "{needle} missing in\n{table}");
    }
}

#[test]
fn verdict_passes_and_fails_per_axis() {
    let reference = grid();
    let mut pred = reference.clone();
    // Every pair: planar 0.25 exactly, dz = -0.125 exactly, so the RMSEs are 0.25 and 0.125.
    for p in &mut pred.positions {
        p[0] += 0.25;
        p[2] -= 0.125;
    }
    let opts = CompareOptions { threshold: 0.5, band_tolerance_nm: 25.0 };
    let judge = |planar: f64, vertical: f64| {
        let acc = AccuracyOptions {
            within: DEFAULT_WITHIN.to_vec(),
            standard: AccuracyStandard { planar, vertical },
            model: DistanceModel::Nearest,
        };
        compare_clouds_with(&pred, &reference, &opts, &acc).unwrap().standard
    };
    // The paper's default passes both axes.
    let v = nn(&pred, &reference, &opts).unwrap().standard;
    assert_eq!((v.planar.rmse, v.vertical.rmse), (0.25, 0.125));
    assert_eq!((v.planar.limit, v.vertical.limit), (0.3, 0.5));
    assert!(v.planar.pass && v.vertical.pass && v.pass, "{v:?}");
    // At the limit passes (RMSE <= limit).
    let v = judge(0.25, 0.125);
    assert!(v.planar.pass && v.vertical.pass && v.pass, "{v:?}");
    // Planar fails only.
    let v = judge(0.2, 0.5);
    assert!(!v.planar.pass && v.vertical.pass && !v.pass, "{v:?}");
    // Vertical fails only.
    let v = judge(0.3, 0.1);
    assert!(v.planar.pass && !v.vertical.pass && !v.pass, "{v:?}");
    // Both fail.
    let v = judge(0.1, 0.1);
    assert!(!v.planar.pass && !v.vertical.pass && !v.pass, "{v:?}");
    let r = compare_clouds_with(
        &pred,
        &reference,
        &opts,
        &AccuracyOptions {
            within: vec![0.2, 0.3],
            standard: AccuracyStandard { planar: 0.2, vertical: 0.5 },
            model: DistanceModel::Nearest,
        },
    )
    .unwrap();
    assert!(r.table().contains("FAIL"), "{}", r.table());
    // Every pair is 0.2795 m away: none within 0.2, all within 0.3 on both sides.
    assert_eq!((r.within[0].pred_fraction, r.within[0].ref_fraction), (0.0, 0.0));
    assert_eq!((r.within[1].pred_fraction, r.within[1].ref_fraction), (1.0, 1.0));
    assert_eq!((r.position.median_signed_dz, r.position.median_elevation), (-0.125, 0.125));
    assert_eq!(r.position.median_planar, 0.25);
    // Bad options given directly to the library are refused too.
    let bad = |within: Vec<f64>, planar: f64| {
        let acc =
            AccuracyOptions { within, standard: AccuracyStandard { planar, vertical: 0.5 }, ..Default::default() };
        compare_clouds_with(&pred, &reference, &opts, &acc).unwrap_err().to_string()
    };
    assert!(bad(vec![], 0.3).contains("--within"));
    assert!(bad(vec![0.1, -1.0], 0.3).contains("--within: `-1`"));
    assert!(bad(vec![0.1], 0.0).contains("--standard: `planar=0`"));
}

#[test]
fn standard_and_within_parsing_name_the_flag_and_the_item() {
    assert_eq!(AccuracyStandard::parse("planar=0.3,vertical=0.5").unwrap(), AccuracyStandard::default());
    assert_eq!(AccuracyStandard::default(), AccuracyStandard { planar: 0.3, vertical: 0.5 });
    assert_eq!(
        AccuracyStandard::parse(" vertical = 0.25 , planar=0.1").unwrap(),
        AccuracyStandard { planar: 0.1, vertical: 0.25 }
    );
    // A key left out keeps the default.
    assert_eq!(AccuracyStandard::parse("vertical=1").unwrap(), AccuracyStandard { planar: 0.3, vertical: 1.0 });
    let err = |s: &str| AccuracyStandard::parse(s).unwrap_err().to_string();
    assert_eq!(err("planar=abc"), "--standard: `planar=abc` is not a number");
    assert!(err("planar=0.3,horizontal=0.2").starts_with("--standard: unknown key in `horizontal=0.2`"));
    assert!(err("planar=0.3,vertical=0.5,planar=0.2").contains("`planar=0.2`: `planar` is given twice"));
    assert!(err("planar").contains("`planar` is not key=value"));
    assert!(err("planar=-0.3").contains("`planar=-0.3` must be a positive"));
    assert!(err("vertical=0").contains("`vertical=0` must be a positive"));
    assert!(err("vertical=inf").contains("`vertical=inf` must be a positive, finite"));
    assert!(err("vertical=NaN").contains("`vertical=NaN` must be a positive, finite"));
    assert!(err("planar=0.3,").starts_with("--standard: `` is not key=value"));
    assert!(err("").starts_with("--standard: empty"));

    assert_eq!(parse_within("0.1,0.25,0.5,1.0").unwrap(), DEFAULT_WITHIN.to_vec());
    assert_eq!(parse_within(" 2 , 0.5").unwrap(), vec![2.0, 0.5]);
    let err = |s: &str| parse_within(s).unwrap_err().to_string();
    assert_eq!(err("0.1,abc"), "--within: `abc` is not a number");
    assert!(err("0.1,-0.5").starts_with("--within: `-0.5` must be a positive"));
    assert!(err("0").starts_with("--within: `0` must be a positive"));
    assert!(err("0.1,inf").starts_with("--within: `inf` must be a positive, finite"));
    assert!(err("0.1,,0.5").starts_with("--within: `` is not a number"));
    assert!(err(" ").starts_with("--within: empty"));
}

#[test]
fn compare_cloud_command_reports_within_bias_and_verdict() {
    let dir = scratch("compare_cli_verdict");
    let reference = grid();
    let mut pred = reference.clone();
    for p in &mut pred.positions {
        p[2] += 0.375;
    }
    let (a, b) = (dir.join("pred.ply"), dir.join("ref.ply"));
    write_ply(&a, &pred, &PlyOptions::default()).unwrap();
    write_ply(&b, &reference, &PlyOptions::default()).unwrap();
    let exe = env!("CARGO_BIN_EXE_msnerf");
    let run = |extra: &[&str]| {
        std::process::Command::new(exe)
            .args(["compare-cloud", "--pred"])
            .arg(&a)
            .arg("--ref")
            .arg(&b)
            .args(extra)
            .output()
            .unwrap()
    };
    let report = dir.join("report.json");
    let out = run(&["--json", "--standard", "vertical=0.25", "--output", report.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let file: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(j, file);
    // Defaults: four thresholds; every pair is 0.375 m apart.
    let w = j["within"].as_array().unwrap();
    assert_eq!(w.iter().map(|x| x["threshold"].as_f64().unwrap()).collect::<Vec<_>>(), DEFAULT_WITHIN.to_vec());
    assert_eq!((w[1]["pred_fraction"].as_f64(), w[2]["ref_fraction"].as_f64()), (Some(0.0), Some(1.0)));
    assert_eq!(j["position"]["median_signed_dz"], 0.375);
    assert_eq!(j["position"]["median_elevation"], 0.375);
    assert_eq!(j["position"]["median_planar"], 0.0);
    assert_eq!(j["standard"]["planar"]["limit"], 0.3);
    assert_eq!(j["standard"]["planar"]["pass"], true);
    assert_eq!(j["standard"]["vertical"]["limit"], 0.25);
    assert_eq!(j["standard"]["vertical"]["rmse"], 0.375);
    assert_eq!(j["standard"]["vertical"]["pass"], false);
    assert_eq!(j["standard"]["pass"], false);

    let out = run(&["--within", "0.5,1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("fraction within") && table.contains("< 0.5") && table.contains("< 1"), "{table}");
    assert!(table.contains("signed dz") && table.contains("RMSE") && table.contains("overall"), "{table}");

    for (flag, value, msg) in [
        ("--standard", "planar=abc", "--standard: `planar=abc` is not a number"),
        ("--standard", "horizontal=0.3", "--standard: unknown key in `horizontal=0.3`"),
        ("--standard", "vertical=-1", "--standard: `vertical=-1` must be a positive"),
        ("--within", "0.1,x", "--within: `x` is not a number"),
        ("--within", "0.1,0", "--within: `0` must be a positive"),
    ] {
        let out = run(&[flag, value]);
        assert!(!out.status.success(), "{flag} {value} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(msg), "{flag} {value}: {err}");
    }
}

/// Points of the plane z = A x + B y + C over [x0, x0 + n·step)², jittered in x and y by up to ±j·step.
fn plane_points(n: usize, step: f64, j: f64, lift: f64, rng: &mut Rng) -> Vec<[f64; 3]> {
    const A: f64 = 0.3;
    const B: f64 = 0.1;
    (0..n * n)
        .map(|i| {
            let x = (i % n) as f64 * step + j * step * (2.0 * rng.f64() - 1.0);
            let y = (i / n) as f64 * step + j * step * (2.0 * rng.f64() - 1.0);
            [500000.0 + x, 4000000.0 + y, 100.0 + A * x + B * y + lift]
        })
        .collect()
}

#[test]
fn local_plane_measures_the_surface_not_its_sampling() {
    let mut rng = Rng(11);
    // Reference: a tilted plane sampled every metre (jittered); prediction: the same plane every 0.25 m over the
    // reference's interior (1 m margin), lifted 0.2 m vertically.
    let reference = PointCloud::new(plane_points(30, 1.0, 0.3, 0.0, &mut rng), vec![], vec![]).unwrap();
    let interior: Vec<[f64; 3]> = plane_points(104, 0.25, 0.0, 0.2, &mut rng)
        .into_iter()
        .map(|p| [p[0] + 1.5, p[1] + 1.5, p[2] + 0.3 * 1.5 + 0.1 * 1.5])
        .collect();
    let pred = PointCloud::new(interior.clone(), vec![], vec![]).unwrap();
    let opts = CompareOptions { threshold: 0.5, band_tolerance_nm: 25.0 };
    let r = compare_clouds(&pred, &reference, &opts).unwrap();
    assert_eq!(r.distance_model, DistanceModel::Plane { k: 6 });
    assert_eq!(r.plane_fraction, 1.0);
    // Independently, in f64: a vertical lift h of the plane z = a x + b y + c is h / |(-a, -b, 1)| from it along
    // the unit normal n; the offset is that distance times n, so dz = h / (1 + a² + b²) and the planar part is
    // h·√(a² + b²) / (1 + a² + b²).
    let (a, b, h) = (0.3f64, 0.1f64, 0.2f64);
    let q = 1.0 + a * a + b * b;
    let (d, dz, planar) = (h / q.sqrt(), h / q, h * (a * a + b * b).sqrt() / q);
    let p = &r.position;
    for (got, want, what) in [
        (r.accuracy.median, d, "median distance"),
        (r.accuracy.max, d, "max distance"),
        (p.median_signed_dz, dz, "median signed dz"),
        (p.rmse_elevation, dz, "vertical RMSE"),
        (p.rmse_planar, planar, "planar RMSE"),
    ] {
        assert!((got - want).abs() < 1e-9, "{what}: {got} vs {want}");
    }
    // The same prediction without the lift: zero to rounding, where the nearest-point distance is the sampling.
    let flat: Vec<[f64; 3]> = interior.iter().map(|p| [p[0], p[1], p[2] - h]).collect();
    let pred0 = PointCloud::new(flat, vec![], vec![]).unwrap();
    let r0 = compare_clouds(&pred0, &reference, &opts).unwrap();
    let n0 = nn(&pred0, &reference, &opts).unwrap();
    assert!(r0.accuracy.max < 1e-9, "on the surface: {:?}", r0.accuracy);
    assert!(n0.accuracy.median > 0.2, "nearest point: {:?}", n0.accuracy);
    // Beyond the reference's edge the plane does not apply: the nearest-point distance stands (brute force).
    let outside = [500000.0 + 35.0, 4000000.0 + 10.0, 100.0 + a * 35.0 + b * 10.0];
    let one = PointCloud::new(vec![outside], vec![], vec![]).unwrap();
    let r1 = compare_clouds(&one, &reference, &opts).unwrap();
    let (_, brute) = brute_nearest(outside, &reference.positions);
    assert_eq!(r1.plane_fraction, 0.0);
    assert!((r1.accuracy.max - brute).abs() < 1e-12, "{} vs {brute}", r1.accuracy.max);
    // The flags.
    assert_eq!(DistanceModel::parse("none", 6).unwrap(), DistanceModel::Nearest);
    assert_eq!(DistanceModel::parse("plane", 8).unwrap(), DistanceModel::Plane { k: 8 });
    assert!(DistanceModel::parse("plane", 2).unwrap_err().to_string().starts_with("--local-k"));
    assert!(DistanceModel::parse("quadric", 6).unwrap_err().to_string().starts_with("--local-model: `quadric`"));
}
