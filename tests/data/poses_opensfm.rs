//! `msnerf import poses --from opensfm | odm` (issue 20, item 2, OpenSfM/ODM part): the simulated `ci-small`
//! cameras written as an OpenSfM reconstruction by a writer in this test (axis-angle world-to-camera from the
//! rotation's quaternion, focal and principal point normalised by max(width, height) and measured from the image
//! centre), a `tracks.csv`, and an ODM project with its UTM offset in `odm_georeferencing/coords.txt` and one
//! camera per band; imported back and compared with the truth within 1e-6 relative.

use crate::common;
use crate::poses_support;
use std::path::Path;

use common::TempDir;
use msnerf::poses::apply_poses;
use msnerf::poses::opensfm::{read_odm, read_reconstruction};
use poses_support::{copy_dataset, stem, truth, Truth};
use serde_json::{json, Value};

/// OpenSfM's shot (rotation as axis-angle, translation) of an OpenGL camera-to-world, world shifted by -offset.
fn shot(c2w: &[[f64; 4]; 4], offset: [f64; 2], camera: &str) -> Value {
    let rc: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| if j == 0 { c2w[i][j] } else { -c2w[i][j] }));
    let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| rc[j][i]));
    let c = [c2w[0][3] - offset[0], c2w[1][3] - offset[1], c2w[2][3]];
    let t: [f64; 3] = std::array::from_fn(|i| -(r[i][0] * c[0] + r[i][1] * c[1] + r[i][2] * c[2]));
    let q = common::quaternion_of(r);
    let v = (q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let theta = 2.0 * v.atan2(q[0]);
    let aa: Vec<f64> = if v < 1e-15 { vec![0.0; 3] } else { q[1..].iter().map(|x| x / v * theta).collect() };
    json!({"rotation": aa, "translation": t, "camera": camera})
}

fn cameras(t: &Truth) -> Value {
    let (w, h) = (t.size.0 as f64, t.size.1 as f64);
    let size = w.max(h);
    let [fx, fy, cx, cy] = t.cam;
    json!({
        "v2 brown": {"projection_type": "brown", "width": w, "height": h, "focal_x": fx / size, "focal_y": fy / size,
                     "c_x": (cx - w / 2.0) / size, "c_y": (cy - h / 2.0) / size, "k1": 0.01, "k2": -0.002, "p1": 0.0003, "p2": 0.0, "k3": 0.0},
        "v2 band1": {"projection_type": "perspective", "width": w, "height": h, "focal": fx / size, "k1": 0.0, "k2": 0.0},
    })
}

fn compare(t: &Truth, data: &Path, expect_frames: usize) -> Value {
    let tj: Value = serde_json::from_str(&std::fs::read_to_string(data.join("transforms.json")).unwrap()).unwrap();
    let frames = tj["frames"].as_array().unwrap();
    assert_eq!(frames.len(), expect_frames);
    let mut worst: f64 = 0.0;
    for f in frames {
        let i = t.names.iter().position(|n| n == f["file_path"].as_str().unwrap()).unwrap();
        for r in 0..4 {
            for c in 0..4 {
                let (got, want) = (f["transform_matrix"][r][c].as_f64().unwrap(), t.c2w[i][r][c]);
                worst = worst.max((got - want).abs() / want.abs().max(1.0));
            }
        }
        for (k, want) in ["fl_x", "fl_y", "cx", "cy"].iter().zip(t.cam) {
            let got = f[*k].as_f64().unwrap();
            assert!((got - want).abs() < 1e-9 * want.abs().max(1.0), "{k}: {got} against {want}");
        }
        assert_eq!(f["camera_model"], "OPENCV");
    }
    eprintln!("largest relative pose difference: {worst:e}");
    assert!(worst < 1e-6, "poses differ by {worst:e}");
    msnerf::data::load_dataset(data, &msnerf::data::LoadOptions::default()).unwrap();
    tj
}

#[test]
fn opensfm_reconstruction_with_tracks_imports_within_1e6() {
    let tmp = TempDir::new("poses-osfm");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = truth(&data);
    let mut shots = serde_json::Map::new();
    for (i, n) in t.names.iter().enumerate() {
        shots.insert(format!("{}.JPG", stem(n)), shot(&t.c2w[i], [0.0, 0.0], "v2 brown"));
    }
    let rec = json!([{"cameras": cameras(&t), "shots": shots,
        "points": {"5": {"coordinates": [0.1, 0.2, 0.3], "color": [200, 100, 50]}, "9": {"coordinates": [1.0, 1.0, 0.0], "color": [1, 2, 3]}}},
        {"cameras": {}, "shots": {}, "points": {}}]);
    let dir = tmp.path().join("opensfm");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("reconstruction.json"), rec.to_string()).unwrap();
    let s0 = stem(&t.names[0]);
    let s1 = stem(&t.names[1]);
    std::fs::write(
        dir.join("tracks.csv"),
        format!("OPENSFM_TRACKS_VERSION_v2\n{s0}.JPG\t5\t0\t0.1\t0.2\t0.01\t200\t100\t50\t-1\t-1\n{s1}.JPG\t5\t3\t0.1\t0.2\t0.01\t200\t100\t50\t-1\t-1\n"),
    )
    .unwrap();
    let d = tmp.path().join("data");
    copy_dataset(&data, &d);
    let m = read_reconstruction(&dir.join("reconstruction.json")).unwrap();
    let rep = apply_poses(&m, &dir, &d).unwrap();
    assert_eq!((rep.registered, rep.unknown_images.len()), (t.names.len(), 0));
    let tj = compare(&t, &d, t.names.len());
    assert_eq!(tj["frames"][0]["k1"], 0.01);
    // Point 5 has a two-frame track; point 9 has none and is left out.
    let sp: Value = serde_json::from_str(&std::fs::read_to_string(d.join("sparse_points.json")).unwrap()).unwrap();
    assert_eq!(sp["points"].as_array().unwrap().len(), 1);
    assert_eq!(sp["points"][0]["frames"].as_array().unwrap().len(), 2);
}

#[test]
fn odm_project_adds_the_utm_offset_and_matches_band_files() {
    let tmp = TempDir::new("poses-odm");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let mut t = truth(&data);
    // The truth in UTM metres: the simulated poses plus a UTM-sized offset.
    let off = [500_123.25, 4_100_456.5];
    for c in &mut t.c2w {
        c[0][3] += off[0];
        c[1][3] += off[1];
    }
    // The dataset as `import rig` writes it: reference band and raw band files per frame (poses: anything).
    let d = tmp.path().join("data");
    copy_dataset(&data, &d);
    let tp = d.join("transforms.json");
    let mut tj: Value = serde_json::from_str(&std::fs::read_to_string(&tp).unwrap()).unwrap();
    let ref_band = tj["bands"][1]["name"].as_str().unwrap().to_string();
    tj["reference_band"] = json!(ref_band);
    for f in tj["frames"].as_array_mut().unwrap() {
        let s = stem(f["file_path"].as_str().unwrap()).to_string();
        f["source_files"] = json!([format!("/flight/{s}_1.tif"), format!("/flight/{s}_2.tif")]);
    }
    std::fs::write(&tp, tj.to_string()).unwrap();
    // ODM multispectral: a shot per band, one camera per band; reconstruction in UTM minus the offset.
    let mut shots = serde_json::Map::new();
    for (i, n) in t.names.iter().enumerate() {
        shots.insert(format!("{}_2.tif", stem(n)), shot(&t.c2w[i], off, "v2 brown"));
        shots.insert(format!("{}_1.tif", stem(n)), shot(&t.c2w[i], off, "v2 band1"));
    }
    let proj = tmp.path().join("odm");
    std::fs::create_dir_all(proj.join("opensfm")).unwrap();
    std::fs::create_dir_all(proj.join("odm_georeferencing")).unwrap();
    std::fs::write(
        proj.join("opensfm/reconstruction.json"),
        json!([{"cameras": cameras(&t), "shots": shots}]).to_string(),
    )
    .unwrap();
    std::fs::write(proj.join("odm_georeferencing/coords.txt"), format!("WGS84 UTM 32N\n{} {}\n", off[0], off[1]))
        .unwrap();
    let m = read_odm(&proj).unwrap();
    let coords_bad = tmp.path().join("coords-bad");
    std::fs::create_dir_all(coords_bad.join("odm_georeferencing")).unwrap();
    std::fs::create_dir_all(coords_bad.join("opensfm")).unwrap();
    std::fs::copy(proj.join("opensfm/reconstruction.json"), coords_bad.join("opensfm/reconstruction.json")).unwrap();
    std::fs::write(coords_bad.join("odm_georeferencing/coords.txt"), "WGS84 UTM 99Q\n1 2\n").unwrap();
    let e = read_odm(&coords_bad).unwrap_err().to_string();
    assert!(e.contains("coords.txt") && e.contains("line 1") && e.contains("99Q"), "{e}");
    assert_eq!(m.crs.as_ref().and_then(|c| c.epsg), Some(32632), "ODM's `WGS84 UTM 32N` is EPSG:32632");
    let rep = apply_poses(&m, &proj, &d).unwrap();
    assert_eq!(rep.registered, t.names.len());
    assert_eq!(rep.unknown_images.len(), t.names.len(), "the other band's shots are listed, not used");
    let tj = compare(&t, &d, t.names.len());
    assert_eq!(tj["pose_source"]["crs"], "EPSG:32632");
    assert_eq!(tj["crs"], "EPSG:32632", "the dataset's crs is the project's");
    assert_eq!(rep.crs.as_deref(), Some("EPSG:32632 (WGS 84 / UTM zone 32N)"));
    assert_eq!(tj["pose_source"]["from"], "odm");

    // Bad input named: an unknown projection type, a shot without its camera, not an ODM project.
    let bad = tmp.path().join("bad.json");
    std::fs::write(
        &bad,
        json!([{"cameras": {"c": {"projection_type": "spherical", "width": 64, "height": 48}}, "shots": {}}])
            .to_string(),
    )
    .unwrap();
    let e = read_reconstruction(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.json") && e.contains("camera c") && e.contains("spherical"), "{e}");
    std::fs::write(
        &bad,
        json!([{"cameras": {}, "shots": {"a.jpg": {"rotation": [0, 0, 0], "translation": [0, 0, 0], "camera": "x"}}}])
            .to_string(),
    )
    .unwrap();
    let e = read_reconstruction(&bad).unwrap_err().to_string();
    assert!(e.contains("shot a.jpg") && e.contains("\"x\""), "{e}");
    let e = read_odm(tmp.path()).unwrap_err().to_string();
    assert!(e.contains("not an ODM project"), "{e}");
}
