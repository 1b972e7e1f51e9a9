//! `msnerf sfm` with Debian's COLMAP (issue 20, item 1): the textured simulated scene (issue 18's texture effect,
//! 256x192 like the paper's campus renders, 24 views) without poses goes through COLMAP; after a similarity
//! alignment the poses are the simulator's within the limits (median rotation error <= 0.2 degree, median
//! centre error <= 0.25% of the scene size, >= 95% of frames registered). A blank frame COLMAP cannot register is
//! listed and moved to `unregistered_frames`. With GPS-like priors (noisy, one of them 200 m off) the model is
//! geo-registered into the dataset's CRS. COLMAP missing or failing is named with the apt line or the step's log,
//! and the dataset is left as it was. COLMAP comes from apt (`tools/setup-debian.sh` installs it); a missing
//! COLMAP fails these tests with the apt line.

use crate::common;
use std::path::Path;

use common::TempDir;
use msnerf::maths::similarity::fit_similarity;
use serde_json::{json, Value};

const BIN: &str = env!("CARGO_BIN_EXE_msnerf");

fn require_colmap() {
    let ok = std::process::Command::new("sh").args(["-c", "command -v colmap"]).output().map(|o| o.status.success());
    assert!(
        ok.unwrap_or(false),
        "COLMAP not found: install it with `apt-get install colmap` (tools/setup-debian.sh does)"
    );
}

fn read(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// Simulates ci-textured at 256x192 into `dir` (with `crs` when given); returns the true transforms.json.
fn simulate(dir: &Path, crs: Option<&str>) -> Value {
    let mut scene = msnerf::sim::SceneDesc::load("ci-textured").unwrap();
    scene.crs = crs.map(str::to_string);
    let opts = msnerf::sim::SimOptions { width: Some(256), ..Default::default() };
    msnerf::sim::simulate(&scene, &opts, dir).unwrap();
    read(&dir.join("transforms.json"))
}

fn centre(m: &Value) -> [f64; 3] {
    [m[0][3].as_f64().unwrap(), m[1][3].as_f64().unwrap(), m[2][3].as_f64().unwrap()]
}

fn rotation(m: &Value) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[i][j].as_f64().unwrap()))
}

/// Angle (degrees) between rotations `a` and `r b` (r = the alignment's rotation).
fn angle_deg(a: [[f64; 3]; 3], r: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> f64 {
    let rb: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| r[i][k] * b[k][j]).sum()));
    let tr: f64 = (0..3).map(|i| (0..3).map(|k| a[k][i] * rb[k][i]).sum::<f64>()).sum();
    ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median centre and rotation errors of the dataset's frames against the truth after mapping the dataset's poses
/// by the least-squares similarity (any similarity bounds the optimal one's errors from above), as fractions of
/// the scene size and degrees; and the scene size.
fn errors(truth: &Value, got: &Value, align: bool) -> (f64, f64, f64, usize) {
    let tf: Vec<&Value> = truth["frames"].as_array().unwrap().iter().collect();
    let by_name = |n: &str| tf.iter().find(|f| f["file_path"] == n).copied().unwrap();
    let gf = got["frames"].as_array().unwrap();
    let src: Vec<[f64; 3]> = gf.iter().map(|f| centre(&f["transform_matrix"])).collect();
    let dst: Vec<[f64; 3]> =
        gf.iter().map(|f| centre(&by_name(f["file_path"].as_str().unwrap())["transform_matrix"])).collect();
    let s = if align {
        fit_similarity(&src, &dst).unwrap()
    } else {
        msnerf::maths::similarity::Similarity {
            scale: 1.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    };
    let all: Vec<[f64; 3]> = tf.iter().map(|f| centre(&f["transform_matrix"])).collect();
    let size = (0..3)
        .map(|k| {
            let (lo, hi) = all.iter().fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p[k]), h.max(p[k])));
            (hi - lo).powi(2)
        })
        .sum::<f64>()
        .sqrt();
    let c: Vec<f64> = src
        .iter()
        .zip(&dst)
        .map(|(a, b)| {
            let p = s.apply(*a);
            ((p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2)).sqrt() / size
        })
        .collect();
    let r: Vec<f64> = gf
        .iter()
        .map(|f| {
            let t = by_name(f["file_path"].as_str().unwrap());
            angle_deg(rotation(&t["transform_matrix"]), s.rotation, rotation(&f["transform_matrix"]))
        })
        .collect();
    (median(c), median(r), size, gf.len())
}

/// Writes to `dst` an image of `src`'s size and band count with every sample `value` (nothing for SIFT to find).
fn flat_copy(src: &Path, dst: &Path, value: f32) {
    let img = msnerf::data::reader::read_image_file(src, 1 << 30).unwrap().raster;
    let n = img.width as usize * img.height as usize * img.bands;
    let data = vec![value; n];
    msnerf::util::tiff::write_tiff(dst, img.width, img.height, img.bands, msnerf::util::tiff::TiffData::F32(&data))
        .unwrap();
}

fn run_sfm(data: &Path, extra: &[&str]) -> std::process::Output {
    std::process::Command::new(BIN).args([&["sfm", data.to_str().unwrap()], extra].concat()).output().unwrap()
}

#[test]
fn colmap_finds_the_true_poses_and_lists_the_frame_it_cannot_register() {
    require_colmap();
    let tmp = TempDir::new("sfm-poses");
    let data = tmp.path().join("data");
    let truth = simulate(&data, None);
    // No poses; one extra frame that is a blank copy of view 0 (nothing for SIFT to find).
    let mut t = truth.clone();
    let frames = t["frames"].as_array_mut().unwrap();
    let mut blank = frames[0].clone();
    for f in frames.iter_mut() {
        f.as_object_mut().unwrap().remove("transform_matrix");
    }
    flat_copy(&data.join(blank["file_path"].as_str().unwrap()), &data.join("images/blank.tif"), 0.3);
    blank["file_path"] = json!("images/blank.tif");
    blank.as_object_mut().unwrap().remove("transform_matrix");
    blank.as_object_mut().unwrap().remove("depth_file_path");
    frames.push(blank);
    std::fs::write(data.join("transforms.json"), serde_json::to_string_pretty(&t).unwrap()).unwrap();

    let out = run_sfm(&data, &["--json"]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    let rep: Value = serde_json::from_str(&String::from_utf8_lossy(&out.stdout)).unwrap();
    eprintln!("{}", serde_json::to_string(&rep).unwrap());
    assert_eq!(rep["frames"], 25);
    assert_eq!(rep["unregistered"], json!(["images/blank.tif"]), "the blank frame is listed");
    let registered = rep["registered"].as_u64().unwrap() as f64 / 25.0;
    assert!(registered >= 0.95, "registered {registered}");
    assert!(rep["mean_reprojection_error_px"].as_f64().unwrap() < 1.0, "{}", rep["mean_reprojection_error_px"]);
    for log in ["feature_extractor.log", "exhaustive_matcher.log", "mapper.log", "sfm_report.json"] {
        assert!(data.join("colmap").join(log).is_file(), "{log} kept");
    }
    let got = read(&data.join("transforms.json"));
    assert_eq!(got["unregistered_frames"][0]["file_path"], "images/blank.tif");
    assert!(data.join("transforms.before-poses.json").is_file(), "the old transforms.json is kept");
    assert!(data.join("sparse_points.json").is_file());
    assert!(got.get("crs").is_none(), "no GPS: COLMAP's frame, no crs");
    // The intrinsics are the dataset's (kept fixed), back at its pixel scale.
    let f0 = &got["frames"][0];
    assert!((f0["fl_x"].as_f64().unwrap() - truth["fl_x"].as_f64().unwrap()).abs() < 1e-9, "{f0}");
    assert_eq!(f0["w"], 256);
    let (c, r, size, n) = errors(&truth, &got, true);
    eprintln!("{n} frames: median centre error {:.4}% of {size:.1} m, median rotation error {r:.4} deg", 100.0 * c);
    assert!(c <= 0.0025, "median centre error {:.4}% of the scene size", 100.0 * c);
    assert!(r <= 0.2, "median rotation error {r} deg");
    // The dataset trains as it is now.
    msnerf::data::load_dataset(&data, &Default::default()).expect("the posed dataset loads");
}

#[test]
fn gps_priors_geo_register_the_model_into_the_datasets_crs() {
    require_colmap();
    let tmp = TempDir::new("sfm-georef");
    let data = tmp.path().join("data");
    let truth = simulate(&data, Some("EPSG:32650"));
    // The true centres with 0.3 m of seeded noise as GPS pose priors in the dataset's CRS; one 200 m off.
    let mut t = truth.clone();
    t["pose_prior"] = json!({"source": "gps", "frame": "EPSG:32650"});
    let mut state = 12345u64;
    let mut noise = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.6
    };
    for (i, f) in t["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
        let m = f["transform_matrix"].as_array_mut().unwrap();
        // A nadir prior's orientation is not the truth's: sfm must use the centres only.
        for (r, row) in m.iter_mut().enumerate().take(3) {
            let c = row[3].as_f64().unwrap() + noise() + if i == 7 && r == 0 { 200.0 } else { 0.0 };
            *row = json!([
                if r == 0 { 1.0 } else { 0.0 },
                if r == 1 { 1.0 } else { 0.0 },
                if r == 2 { 1.0 } else { 0.0 },
                c
            ]);
        }
    }
    std::fs::write(data.join("transforms.json"), serde_json::to_string_pretty(&t).unwrap()).unwrap();
    // Spatial matching from the priors: each frame with its 10 nearest (COLMAP's matches_importer on a pair list).
    let out = run_sfm(&data, &["--json", "--matcher", "spatial", "--overlap", "10"]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    let rep: Value = serde_json::from_str(&String::from_utf8_lossy(&out.stdout)).unwrap();
    assert_eq!(rep["matcher"], "spatial");
    let pairs = std::fs::read_to_string(data.join("colmap/pairs.txt")).unwrap();
    let n_pairs = pairs.lines().count();
    assert!((24 * 10 / 2..=24 * 10).contains(&n_pairs), "{n_pairs} pairs");
    assert!(data.join("colmap/matches_importer.log").is_file());
    let g = &rep["georef"];
    eprintln!("georef: {g}");
    assert_eq!(g["rejected"], json!([truth["frames"][7]["file_path"]]), "the 200 m prior is left out, named");
    assert!(g["rms_m"].as_f64().unwrap() < 0.5);
    let got = read(&data.join("transforms.json"));
    assert_eq!(got["crs"], "EPSG:32650");
    assert!(got.get("pose_prior").is_none(), "priors replaced by SfM poses");
    // Without any alignment in the test: the poses are the truth's, in the world (UTM) frame.
    let (c, r, size, _) = errors(&truth, &got, false);
    eprintln!("georeferenced: median centre error {:.3} m, rotation {r:.3} deg", c * size);
    assert!(c * size < 0.25, "median centre error {} m", c * size);
    // The cameras orbit at one height: the priors' noise tilts the fit by ~0.1-0.3 degrees (measured 0.26).
    assert!(r < 0.5, "median rotation error {r} deg");
}

#[test]
fn colmap_missing_or_failing_is_named_and_the_dataset_is_left_alone() {
    require_colmap();
    let tmp = TempDir::new("sfm-bad");
    let data = tmp.path().join("data");
    common::simulate_ci_small(&data);
    let before = std::fs::read(data.join("transforms.json")).unwrap();
    let out = run_sfm(&data, &["--colmap", "/nonexistent/colmap"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("apt-get install colmap") && e.contains("/nonexistent/colmap"), "{e}");
    let out = run_sfm(&data, &["--band", "UV"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("--band") && e.contains("`UV`") && e.contains("nir"), "{e}");
    // Flat images: COLMAP finds nothing to map; the failing step and its log are named.
    let t = read(&data.join("transforms.json"));
    for f in t["frames"].as_array().unwrap() {
        let p = data.join(f["file_path"].as_str().unwrap());
        flat_copy(&p, &p, 0.2);
    }
    let out = run_sfm(&data, &[]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("COLMAP step `mapper`") && e.contains("mapper.log"), "{e}");
    assert!(data.join("colmap/mapper.log").is_file());
    assert_eq!(std::fs::read(data.join("transforms.json")).unwrap(), before, "transforms.json untouched");
    assert!(!data.join("transforms.before-poses.json").exists());
    // Two frames with one file stem cannot be told apart in COLMAP's image folder: named.
    let mut t2 = t.clone();
    let dup = t2["frames"][0].clone();
    let p = dup["file_path"].as_str().unwrap().replace("images/", "");
    std::fs::create_dir_all(data.join("other")).unwrap();
    std::fs::copy(data.join("images").join(&p), data.join("other").join(&p)).unwrap();
    let mut d2 = dup.clone();
    d2["file_path"] = json!(format!("other/{p}"));
    t2["frames"].as_array_mut().unwrap().push(d2);
    std::fs::write(data.join("transforms.json"), serde_json::to_string(&t2).unwrap()).unwrap();
    let out = run_sfm(&data, &[]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("share the file stem"), "{e}");
}
