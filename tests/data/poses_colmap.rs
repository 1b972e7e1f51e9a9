//! `msnerf import poses --from colmap` (issue 20, item 2, COLMAP part): the simulated `ci-small` cameras written
//! as COLMAP text and binary models by a writer in this test (COLMAP's documented format, world-to-camera
//! quaternions from the rotation matrix by Shepperd's method, OpenCV axes), imported back into the dataset and
//! compared with the truth within 1e-6 relative; sparse points, unregistered frames, unknown images, the backup,
//! and bad models refused by name.

use crate::common;
use crate::poses_support;
use std::io::Write;
use std::path::Path;

use common::TempDir;
use msnerf::poses::colmap::read_model;
use msnerf::poses::colmap::to_pose_model;
use msnerf::poses::{apply_poses, PoseModel};
use poses_support::{stem, truth, Truth};
use serde_json::{json, Value};

fn pm(m: &msnerf::poses::colmap::ColmapModel, dir: &Path) -> PoseModel {
    to_pose_model(m, dir).unwrap()
}

/// COLMAP's world-to-camera (quaternion qw qx qy qz, translation) of an OpenGL camera-to-world.
fn colmap_pose(c2w: &[[f64; 4]; 4]) -> ([f64; 4], [f64; 3]) {
    // OpenGL -> OpenCV camera axes: negate the camera's y and z columns; then invert.
    let rc: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| if j == 0 { c2w[i][j] } else { -c2w[i][j] }));
    let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| rc[j][i])); // R_w2c = R_c2w^T
    let c = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let t: [f64; 3] = std::array::from_fn(|i| -(r[i][0] * c[0] + r[i][1] * c[1] + r[i][2] * c[2]));
    let q = common::quaternion_of(r);
    (q, t)
}

/// Image list of the model: (id, name as COLMAP would have it, frame index), `skip` frames left out, plus a ghost.
fn model_images(t: &Truth, skip: &[usize]) -> Vec<(u32, String, Option<usize>)> {
    let mut v: Vec<_> = (0..t.names.len())
        .filter(|i| !skip.contains(i))
        .map(|i| (i as u32 + 1, format!("rgb/{}.png", stem(&t.names[i])), Some(i)))
        .collect();
    v.push((999, "ghost_0001.png".into(), None));
    v
}

/// Three points with tracks through images 1-3 (ids).
const POINTS: [(u64, [f64; 3], &[u32]); 3] =
    [(1, [0.5, -0.25, 0.0], &[1, 2, 3]), (2, [-1.0, 2.0, 0.1], &[2, 999]), (7, [0.0, 0.0, -0.5], &[999])];

fn write_text(dir: &Path, t: &Truth, skip: &[usize], model: &str) {
    std::fs::create_dir_all(dir).unwrap();
    let [fx, fy, cx, cy] = t.cam;
    let params = match model {
        "PINHOLE" => format!("{fx} {fy} {cx} {cy}"),
        _ => format!("{fx} {cx} {cy} 0.1 0.2"),
    };
    std::fs::write(dir.join("cameras.txt"), format!("# Camera list\n1 {model} {} {} {params}\n", t.size.0, t.size.1))
        .unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n");
    for (id, name, fi) in model_images(t, skip) {
        let (q, tr) = colmap_pose(&t.c2w[fi.unwrap_or(0)]);
        s += &format!("{id} {} {} {} {} {} {} {} 1 {name}\n", q[0], q[1], q[2], q[3], tr[0], tr[1], tr[2]);
        s += if id % 2 == 0 { "\n" } else { "10.5 20.5 -1 30.0 40.0 1\n" };
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let mut p = String::from("# 3D point list\n");
    for (id, xyz, track) in POINTS {
        p += &format!("{id} {} {} {} 10 20 30 0.5", xyz[0], xyz[1], xyz[2]);
        for im in track {
            p += &format!(" {im} 0");
        }
        p += "\n";
    }
    std::fs::write(dir.join("points3D.txt"), p).unwrap();
}

fn write_binary(dir: &Path, t: &Truth, skip: &[usize]) {
    std::fs::create_dir_all(dir).unwrap();
    let [fx, fy, cx, cy] = t.cam;
    let mut b = Vec::new();
    b.extend(1u64.to_le_bytes());
    b.extend(1i32.to_le_bytes());
    b.extend(1i32.to_le_bytes()); // PINHOLE
    b.extend(t.size.0.to_le_bytes());
    b.extend(t.size.1.to_le_bytes());
    for v in [fx, fy, cx, cy] {
        b.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("cameras.bin"), b).unwrap();
    let ims = model_images(t, skip);
    let mut b = Vec::new();
    b.extend((ims.len() as u64).to_le_bytes());
    for (id, name, fi) in ims {
        let (q, tr) = colmap_pose(&t.c2w[fi.unwrap_or(0)]);
        b.extend((id as i32).to_le_bytes());
        for v in q.iter().chain(&tr) {
            b.extend(v.to_le_bytes());
        }
        b.extend(1i32.to_le_bytes());
        b.extend(name.as_bytes());
        b.push(0);
        b.extend(1u64.to_le_bytes());
        b.extend(12.5f64.to_le_bytes());
        b.extend(7.25f64.to_le_bytes());
        b.extend((-1i64).to_le_bytes());
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend((POINTS.len() as u64).to_le_bytes());
    for (id, xyz, track) in POINTS {
        b.extend(id.to_le_bytes());
        for v in xyz {
            b.extend(v.to_le_bytes());
        }
        b.extend([10u8, 20, 30]);
        b.extend(0.5f64.to_le_bytes());
        b.extend((track.len() as u64).to_le_bytes());
        for im in track {
            b.extend((*im as i32).to_le_bytes());
            b.extend(0i32.to_le_bytes());
        }
    }
    std::fs::write(dir.join("points3D.bin"), b).unwrap();
}

/// The dataset with every pose replaced by the identity (so the import must supply them).
fn unposed_copy(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            let d = dst.join(p.file_name().unwrap());
            std::fs::create_dir_all(&d).unwrap();
            for f in std::fs::read_dir(&p).unwrap() {
                let f = f.unwrap().path();
                std::fs::copy(&f, d.join(f.file_name().unwrap())).unwrap();
            }
        } else {
            std::fs::copy(&p, dst.join(p.file_name().unwrap())).unwrap();
        }
    }
    let tp = dst.join("transforms.json");
    let mut t: Value = serde_json::from_str(&std::fs::read_to_string(&tp).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        f["transform_matrix"] =
            json!([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
    }
    std::fs::write(&tp, serde_json::to_string_pretty(&t).unwrap()).unwrap();
}

fn check_import(t: &Truth, data: &Path, skip: &[usize]) {
    let tj: Value = serde_json::from_str(&std::fs::read_to_string(data.join("transforms.json")).unwrap()).unwrap();
    let frames = tj["frames"].as_array().unwrap();
    assert_eq!(frames.len(), t.names.len() - skip.len());
    let mut worst: f64 = 0.0;
    for f in frames {
        let name = f["file_path"].as_str().unwrap();
        let i = t.names.iter().position(|n| n == name).unwrap();
        for r in 0..4 {
            for c in 0..4 {
                let got = f["transform_matrix"][r][c].as_f64().unwrap();
                let want = t.c2w[i][r][c];
                worst = worst.max((got - want).abs() / want.abs().max(1.0));
            }
        }
        assert_eq!([f["fl_x"].as_f64(), f["fl_y"].as_f64(), f["cx"].as_f64(), f["cy"].as_f64()], t.cam.map(Some));
        assert_eq!((f["w"].as_u64().unwrap(), f["h"].as_u64().unwrap()), t.size);
    }
    eprintln!("largest relative pose difference: {worst:e}");
    assert!(worst < 1e-6, "poses differ by {worst:e} (relative)");
    let u = tj["unregistered_frames"].as_array().map(|a| a.len()).unwrap_or(0);
    assert_eq!(u, skip.len());
    assert!(data.join("transforms.before-poses.json").is_file());
    // The dataset loads, with the sparse points (tracks by frame name; the ghost image's point is gone).
    let sp: Value = serde_json::from_str(&std::fs::read_to_string(data.join("sparse_points.json")).unwrap()).unwrap();
    let pts = sp["points"].as_array().unwrap();
    assert_eq!(pts.len(), 2, "{sp}");
    assert_eq!(pts[0]["frames"].as_array().unwrap().len(), 3 - skip.iter().filter(|&&s| s < 3).count());
    let ds = msnerf::data::load_dataset(data, &msnerf::data::LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), t.names.len() - skip.len());
}

#[test]
fn colmap_text_and_binary_models_import_within_1e6() {
    let tmp = TempDir::new("poses-colmap");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = truth(&data);
    for (kind, skip) in [("text", vec![]), ("bin", vec![4usize]), ("text", vec![0, 7])] {
        let model = tmp.path().join(format!("model-{kind}-{}", skip.len()));
        if kind == "text" {
            write_text(&model, &t, &skip, "PINHOLE");
        } else {
            write_binary(&model, &t, &skip);
        }
        let d = tmp.path().join(format!("data-{kind}-{}", skip.len()));
        unposed_copy(&data, &d);
        let m = read_model(&model).unwrap();
        assert_eq!(m.images.len(), t.names.len() - skip.len() + 1);
        // The 2-D points (the bundle adjustment's observations), as written above.
        for im in &m.images {
            let want: Vec<[f64; 2]> = match (kind, im.id % 2) {
                ("bin", _) => vec![[12.5, 7.25]],
                (_, 0) => vec![],
                _ => vec![[10.5, 20.5], [30.0, 40.0]],
            };
            assert_eq!(im.points2d, want, "{kind} image {}", im.id);
        }
        assert!(m.points.iter().all(|p| p.point2d.len() == p.images.len() && p.point2d.iter().all(|&k| k == 0)));
        let rep = apply_poses(&pm(&m, &model), &model, &d).unwrap();
        assert_eq!(rep.registered, t.names.len() - skip.len());
        assert_eq!(rep.unknown_images, vec!["ghost_0001.png".to_string()]);
        assert_eq!(rep.unregistered.len(), skip.len());
        for s in &skip {
            assert!(rep.unregistered.contains(&t.names[*s]), "{rep:?}");
        }
        assert_eq!(rep.mean_reprojection_error_px, Some(0.5));
        check_import(&t, &d, &skip);
    }
}

#[test]
fn radial_cameras_become_opencv_and_bad_models_are_named() {
    let tmp = TempDir::new("poses-bad");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = truth(&data);
    // RADIAL (f, cx, cy, k1, k2) -> OPENCV with k1, k2.
    let model = tmp.path().join("radial");
    write_text(&model, &t, &[], "RADIAL");
    let d = tmp.path().join("d-radial");
    unposed_copy(&data, &d);
    apply_poses(&pm(&read_model(&model).unwrap(), &model), &model, &d).unwrap();
    let tj: Value = serde_json::from_str(&std::fs::read_to_string(d.join("transforms.json")).unwrap()).unwrap();
    let f = &tj["frames"][0];
    assert_eq!(
        (f["camera_model"].as_str(), f["k1"].as_f64(), f["k2"].as_f64()),
        (Some("OPENCV"), Some(0.1), Some(0.2))
    );

    // A camera of another size than the dataset's images: the image named.
    let wrong = tmp.path().join("wrong");
    write_text(
        &wrong,
        &Truth { size: (t.size.0 * 2, t.size.1), cam: t.cam, names: t.names.clone(), c2w: t.c2w.clone() },
        &[],
        "PINHOLE",
    );
    let d2 = tmp.path().join("d-wrong");
    unposed_copy(&data, &d2);
    let before = std::fs::read_to_string(d2.join("transforms.json")).unwrap();
    let e = apply_poses(&pm(&read_model(&wrong).unwrap(), &wrong), &wrong, &d2).unwrap_err().to_string();
    assert!(e.contains("images.txt") || e.contains("wrong"), "{e}");
    assert!(e.contains(&format!("{}x{}", t.size.0 * 2, t.size.1)) && e.contains(stem(&t.names[0])), "{e}");
    assert_eq!(std::fs::read_to_string(d2.join("transforms.json")).unwrap(), before, "nothing written on error");

    // A model made on the images at 3x (COLMAP on upsampled or full-size originals): the intrinsics come back at the
    // dataset's size, the distortion untouched; 2x one way only stays refused (above).
    let big = tmp.path().join("big");
    let c3 = t.cam.map(|v| v * 3.0);
    write_text(
        &big,
        &Truth { size: (t.size.0 * 3, t.size.1 * 3), cam: c3, names: t.names.clone(), c2w: t.c2w.clone() },
        &[],
        "RADIAL",
    );
    let d3 = tmp.path().join("d-big");
    unposed_copy(&data, &d3);
    apply_poses(&pm(&read_model(&big).unwrap(), &big), &big, &d3).unwrap();
    let tj: Value = serde_json::from_str(&std::fs::read_to_string(d3.join("transforms.json")).unwrap()).unwrap();
    for f in tj["frames"].as_array().unwrap() {
        assert_eq!((f["w"].as_u64().unwrap(), f["h"].as_u64().unwrap()), t.size);
        // RADIAL has one focal length (the test's fx) and k1, k2 as written.
        let want = [t.cam[0], t.cam[0], t.cam[2], t.cam[3]];
        for (k, w) in ["fl_x", "fl_y", "cx", "cy"].iter().zip(want) {
            let got = f[*k].as_f64().unwrap();
            assert!((got - w).abs() <= 1e-9 * w.abs(), "{k}: {got} vs {w}");
        }
        assert_eq!((f["k1"].as_f64(), f["k2"].as_f64()), (Some(0.1), Some(0.2)));
    }

    // Numbers the reader accepts but that make no camera: a negative focal length, a NaN translation. The import
    // checks the dataset it would write with the dataset's own parser: the model, the frame and the key are named,
    // and nothing is written (no new transforms.json, no backup).
    let [fx, fy, cx, cy] = t.cam;
    for (name, key) in [("negative-focal", "fl_x"), ("nan-translation", "transform_matrix")] {
        let m = tmp.path().join(name);
        write_text(&m, &t, &[], "PINHOLE");
        if key == "fl_x" {
            let cams = format!("1 PINHOLE {} {} {} {fy} {cx} {cy}\n", t.size.0, t.size.1, -fx);
            std::fs::write(m.join("cameras.txt"), cams).unwrap();
        } else {
            let text = std::fs::read_to_string(m.join("images.txt")).unwrap();
            let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
            let mut first: Vec<String> = lines[1].split(' ').map(str::to_owned).collect();
            first[5] = "nan".into();
            lines[1] = first.join(" ");
            std::fs::write(m.join("images.txt"), lines.join("\n") + "\n").unwrap();
        }
        let d = tmp.path().join(format!("d-{name}"));
        unposed_copy(&data, &d);
        let before = std::fs::read_to_string(d.join("transforms.json")).unwrap();
        let points_before = std::fs::read(d.join("sparse_points.json")).ok();
        let e = apply_poses(&pm(&read_model(&m).unwrap(), &m), &m, &d).unwrap_err().to_string();
        assert!(
            e.contains(name) && e.contains("nothing was written") && e.contains(key) && e.contains("frame "),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(d.join("transforms.json")).unwrap(), before, "{name}: nothing written");
        assert!(!d.join("transforms.before-poses.json").exists(), "{name}: no backup of an import that did not happen");
        assert_eq!(std::fs::read(d.join("sparse_points.json")).ok(), points_before, "{name}: points untouched");
    }

    // An unknown camera model, a wrong parameter count, a truncated binary file: file and record named.
    let m = tmp.path().join("fov");
    write_text(&m, &t, &[], "PINHOLE");
    std::fs::write(m.join("cameras.txt"), "1 NOT_A_MODEL 64 48 1 2 3\n").unwrap();
    let e = read_model(&m).unwrap_err().to_string();
    assert!(e.contains("cameras.txt") && e.contains("line 1") && e.contains("NOT_A_MODEL"), "{e}");
    std::fs::write(m.join("cameras.txt"), "1 PINHOLE 64 48 1 2 3\n").unwrap();
    let e = read_model(&m).unwrap_err().to_string();
    assert!(e.contains("PINHOLE takes 4 parameters, 3 given"), "{e}");
    let b = tmp.path().join("trunc");
    write_binary(&b, &t, &[]);
    let bytes = std::fs::read(b.join("images.bin")).unwrap();
    std::fs::File::create(b.join("images.bin")).unwrap().write_all(&bytes[..bytes.len() / 2]).unwrap();
    let e = read_model(&b).unwrap_err().to_string();
    assert!(e.contains("images.bin") && (e.contains("larger than the file") || e.contains("ends early")), "{e}");
    // Cut inside the last image's record instead: that record is named.
    std::fs::File::create(b.join("images.bin")).unwrap().write_all(&bytes[..bytes.len() - 10]).unwrap();
    let e = read_model(&b).unwrap_err().to_string();
    assert!(e.contains("images.bin") && e.contains(&format!("image {}", t.names.len())), "{e}");
    // No model at all.
    let e = read_model(tmp.path()).unwrap_err().to_string();
    assert!(e.contains("no COLMAP model"), "{e}");
}
