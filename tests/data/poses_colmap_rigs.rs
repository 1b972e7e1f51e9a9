//! COLMAP >= 3.12 rig models (`rigs.*`, `frames.*`; issue 20): a two-camera rig (a reference camera and one offset
//! by a known `sensor_from_rig`) over the simulated `ci-small` views, written as text and binary models in
//! COLMAP 3.12's layout by this test. The second camera's poses in `images.*` are deliberately wrong: COLMAP
//! discards them when frames exist, and so must msnerf. Expected poses are composed here with 3x3 matrices from the
//! textbook quaternion formula (not the reader's quaternion products). Bad rig files are named.

use crate::common;
use crate::poses_support;
use std::path::Path;

use common::TempDir;
use msnerf::poses::colmap::{read_model, to_pose_model};

/// Rotation (row-major) of a unit quaternion (w, x, y, z).
fn rot(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

fn apply(a: [[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| (0..3).map(|k| a[i][k] * v[k]).sum())
}

/// World-to-camera (OpenCV axes) of an OpenGL camera-to-world.
fn w2c(c2w: &[[f64; 4]; 4]) -> ([[f64; 3]; 3], [f64; 3]) {
    let rc: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| if j == 0 { c2w[i][j] } else { -c2w[i][j] }));
    let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| rc[j][i]));
    let c = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let t = apply(r, c).map(|v| -v);
    (r, t)
}

/// OpenGL camera-to-world of a world-to-camera (OpenCV axes).
fn c2w(r: [[f64; 3]; 3], t: [f64; 3]) -> [[f64; 4]; 4] {
    let rt: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[j][i]));
    let c = apply(rt, t).map(|v| -v);
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = if j == 0 { rt[i][j] } else { -rt[i][j] };
        }
        m[i][3] = c[i];
    }
    m[3][3] = 1.0;
    m
}

/// The rig's second camera: 4 degrees about (1, 2, 2)/3, 6 cm across.
const S_Q: [f64; 4] = [0.999390827019096, 0.011635, 0.023270, 0.023270];
const S_T: [f64; 3] = [0.06, -0.01, 0.005];

/// A COLMAP pose: quaternion (w, x, y, z) and translation.
type Pose = ([f64; 4], [f64; 3]);

struct Model {
    /// (image id, camera id, name, true world-to-camera, pose written in the images file)
    images: Vec<(u32, u32, String, Pose, Pose)>,
    /// (frame id, rig_from_world, image ids)
    frames: Vec<(u32, Pose, [u32; 2])>,
    expected: Vec<[[f64; 4]; 4]>,
}

fn model(t: &poses_support::Truth) -> Model {
    let s_q = {
        let n = S_Q.iter().map(|v| v * v).sum::<f64>().sqrt();
        S_Q.map(|v| v / n)
    };
    let rs = rot(s_q);
    let mut m = Model { images: vec![], frames: vec![], expected: vec![] };
    for (k, cw) in t.c2w.iter().enumerate() {
        let (r, tr) = w2c(cw);
        let q = common::quaternion_of(r);
        let (ra, rb) = (2 * k as u32 + 1, 2 * k as u32 + 2);
        let rb_r = mul(rs, r);
        let rb_t = {
            let v = apply(rs, tr);
            [v[0] + S_T[0], v[1] + S_T[1], v[2] + S_T[2]]
        };
        m.images.push((ra, 1, format!("a/view_{k:02}.png"), (q, tr), (q, tr)));
        // The second camera's pose in the images file is the first camera's: wrong on purpose.
        m.images.push((rb, 2, format!("b/view_{k:02}.png"), (common::quaternion_of(rb_r), rb_t), (q, tr)));
        m.frames.push((100 + k as u32, (q, tr), [ra, rb]));
        m.expected.push(c2w(r, tr));
        m.expected.push(c2w(rb_r, rb_t));
    }
    m
}

fn write_text(dir: &Path, t: &poses_support::Truth, m: &Model, rig_pose: bool) {
    std::fs::create_dir_all(dir).unwrap();
    let [fx, fy, cx, cy] = t.cam;
    let (w, h) = t.size;
    std::fs::write(
        dir.join("cameras.txt"),
        format!("1 PINHOLE {w} {h} {fx} {fy} {cx} {cy}\n2 PINHOLE {w} {h} {fx} {fy} {cx} {cy}\n"),
    )
    .unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n");
    for (id, cam, name, _, (q, tr)) in &m.images {
        s += &format!("{id} {} {} {} {} {} {} {} {cam} {name}\n\n", q[0], q[1], q[2], q[3], tr[0], tr[1], tr[2]);
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let pose = if rig_pose {
        format!("1 {} {} {} {} {} {} {}", S_Q[0], S_Q[1], S_Q[2], S_Q[3], S_T[0], S_T[1], S_T[2])
    } else {
        "0".to_string()
    };
    std::fs::write(
        dir.join("rigs.txt"),
        format!("# Rig calib list\n# Number of rigs: 1\n1 2 CAMERA 1 CAMERA 2 {pose}\n"),
    )
    .unwrap();
    let mut f = String::from("# Frame list\n");
    for (id, (q, tr), ims) in &m.frames {
        f += &format!(
            "{id} 1 {} {} {} {} {} {} {} 2 CAMERA 1 {} CAMERA 2 {}\n",
            q[0], q[1], q[2], q[3], tr[0], tr[1], tr[2], ims[0], ims[1]
        );
    }
    std::fs::write(dir.join("frames.txt"), f).unwrap();
}

fn write_binary(dir: &Path, t: &poses_support::Truth, m: &Model) {
    std::fs::create_dir_all(dir).unwrap();
    let [fx, fy, cx, cy] = t.cam;
    let mut b = Vec::new();
    b.extend(2u64.to_le_bytes());
    for id in [1i32, 2] {
        b.extend(id.to_le_bytes());
        b.extend(1i32.to_le_bytes());
        b.extend(t.size.0.to_le_bytes());
        b.extend(t.size.1.to_le_bytes());
        for v in [fx, fy, cx, cy] {
            b.extend(v.to_le_bytes());
        }
    }
    std::fs::write(dir.join("cameras.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend((m.images.len() as u64).to_le_bytes());
    for (id, cam, name, _, (q, tr)) in &m.images {
        b.extend(id.to_le_bytes());
        for v in q.iter().chain(tr) {
            b.extend(v.to_le_bytes());
        }
        b.extend(cam.to_le_bytes());
        b.extend(name.as_bytes());
        b.push(0);
        b.extend(0u64.to_le_bytes());
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend(1u64.to_le_bytes());
    b.extend(1u32.to_le_bytes());
    b.extend(2u32.to_le_bytes());
    b.extend(0i32.to_le_bytes()); // CAMERA
    b.extend(1u32.to_le_bytes());
    b.extend(0i32.to_le_bytes());
    b.extend(2u32.to_le_bytes());
    b.push(1);
    for v in S_Q.iter().chain(&S_T) {
        b.extend(v.to_le_bytes());
    }
    std::fs::write(dir.join("rigs.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend((m.frames.len() as u64).to_le_bytes());
    for (id, (q, tr), ims) in &m.frames {
        b.extend(id.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        for v in q.iter().chain(tr) {
            b.extend(v.to_le_bytes());
        }
        b.extend(2u32.to_le_bytes());
        for (cam, im) in [(1u32, ims[0]), (2, ims[1])] {
            b.extend(0i32.to_le_bytes());
            b.extend(cam.to_le_bytes());
            b.extend(u64::from(im).to_le_bytes());
        }
    }
    std::fs::write(dir.join("frames.bin"), b).unwrap();
}

#[test]
fn rig_models_pose_each_camera_from_its_frame_and_rig() {
    let tmp = TempDir::new("colmap-rigs");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = poses_support::truth(&data);
    let m = model(&t);
    for (kind, dir) in [("text", tmp.path().join("text")), ("binary", tmp.path().join("bin"))] {
        if kind == "text" {
            write_text(&dir, &t, &m, true);
        } else {
            write_binary(&dir, &t, &m);
        }
        let cm = read_model(&dir).unwrap();
        let rigs = cm.rigs.as_ref().expect("rigs read");
        assert_eq!((rigs.rigs.len(), rigs.frames.len()), (1, t.c2w.len()), "{kind}");
        assert!(rigs.max_rotation_diff_deg > 3.0, "{kind}: the images file's wrong poses are measured: {rigs:?}");
        let pm = to_pose_model(&cm, &dir).unwrap();
        assert!(pm.notes.iter().any(|n| n.contains("1 rig(s) (2 sensors)")), "{:?}", pm.notes);
        let mut worst: f64 = 0.0;
        for (im, want) in pm.images.iter().zip(&m.expected) {
            for (got_row, want_row) in im.c2w.iter().zip(want).take(3) {
                for (g, w) in got_row.iter().zip(want_row) {
                    worst = worst.max((g - w).abs() / w.abs().max(1.0));
                }
            }
        }
        eprintln!("{kind}: largest relative difference {worst:e}");
        assert!(worst < 1e-9, "{kind}: {worst}");
    }
}

#[test]
fn bad_rig_files_are_named() {
    let tmp = TempDir::new("colmap-rigs-bad");
    let data = tmp.path().join("truth");
    common::simulate_ci_small(&data);
    let t = poses_support::truth(&data);
    let m = model(&t);
    let dir = tmp.path().join("m");
    write_text(&dir, &t, &m, true);
    std::fs::remove_file(dir.join("frames.txt")).unwrap();
    let e = read_model(&dir).unwrap_err().to_string();
    assert!(e.contains("rigs.txt without frames.txt"), "{e}");
    write_text(&dir, &t, &m, false);
    let e = read_model(&dir).unwrap_err().to_string();
    assert!(e.contains("rig 1") && e.contains("no sensor_from_rig"), "{e}");
    write_text(&dir, &t, &m, true);
    let frames = std::fs::read_to_string(dir.join("frames.txt")).unwrap();
    let cut: String = frames.lines().filter(|l| !l.starts_with("100 ")).map(|l| format!("{l}\n")).collect();
    std::fs::write(dir.join("frames.txt"), cut).unwrap();
    let e = read_model(&dir).unwrap_err().to_string();
    assert!(e.contains("image 1 (a/view_00.png)") && e.contains("no frame holds"), "{e}");
    std::fs::write(dir.join("frames.txt"), frames.replace("CAMERA 2", "LIDAR 2")).unwrap();
    let e = read_model(&dir).unwrap_err().to_string();
    assert!(e.contains("frames.txt") && e.contains("LIDAR"), "{e}");
}
