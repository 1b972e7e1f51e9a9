//! Pose normalisation (f64, UTM offsets, nerfstudio's dataparser_transforms.json) and camera rays
//! (pinhole by hand, OPENCV undistortion by Newton, fisheye).

#![allow(clippy::needless_range_loop)] // index math mirrors the formulas
use msnerf::data::camera::{distort, undistort, Camera, CameraModel, Distortion};
use msnerf::data::pose::{normalize_poses, Mat4, PoseTransform};

fn pose(r: [[f64; 3]; 3], t: [f64; 3]) -> Mat4 {
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[i][j];
        }
        m[i][3] = t[i];
    }
    m[3][3] = 1.0;
    m
}

fn rot(ax: f64, ay: f64) -> [[f64; 3]; 3] {
    let (sx, cx) = ax.sin_cos();
    let (sy, cy) = ay.sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = (0..3).map(|k| rx[i][k] * ry[k][j]).sum();
        }
    }
    r
}

#[test]
fn hand_computed_small_case() {
    // Identity rotations: up = +Y → rotate +Y to +Z (x stays, y→z, z→−y). Centres (0,0,0) and (2,0,0).
    let i3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let t = normalize_poses(&[pose(i3, [0.0, 0.0, 0.0]), pose(i3, [2.0, 0.0, 0.0])]);
    let expect = [[1.0, 0.0, 0.0, -1.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0]];
    for i in 0..3 {
        for j in 0..4 {
            assert!((t.transform[i][j] - expect[i][j]).abs() < 1e-7, "{:?}", t.transform);
        }
    }
    assert_eq!(t.scale, 1.0);
    let q = t.to_normalized([2.0, 0.0, 0.0]);
    assert!((q[0] - 1.0).abs() < 1e-12 && q[1].abs() < 1e-12 && q[2].abs() < 1e-12);
    let p = t.to_normalized([1.0, 3.0, 5.0]);
    assert!((p[0]).abs() < 1e-7 && (p[1] + 5.0).abs() < 1e-7 && (p[2] - 3.0).abs() < 1e-7, "{p:?}");
    // Serialises like nerfstudio's dataparser_transforms.json.
    let j: serde_json::Value = serde_json::from_str(&t.to_json()).unwrap();
    assert_eq!(j["transform"].as_array().unwrap().len(), 3);
    assert_eq!(j["transform"][0].as_array().unwrap().len(), 4);
    assert_eq!(j["scale"], 1.0);
    let back: PoseTransform = serde_json::from_value(j).unwrap();
    assert_eq!(back, t);
}

#[test]
fn utm_offset_poses_round_trip_within_a_micrometre() {
    let mut poses = Vec::new();
    for k in 0..50 {
        let a = k as f64 * 0.37;
        let t = [512_345.678 + 80.0 * a.cos(), 4_123_456.789 + 60.0 * a.sin(), 150.0 + k as f64 * 0.1];
        poses.push(pose(rot(0.1 * a.sin(), 0.2 * a.cos()), t));
    }
    let tf = normalize_poses(&poses);
    let mut max_abs: f64 = 0.0;
    for p in &poses {
        let n = tf.pose_to_normalized(p);
        for i in 0..3 {
            max_abs = max_abs.max(n[i][3].abs());
        }
        let w = tf.pose_to_world(&n);
        for i in 0..3 {
            for j in 0..4 {
                assert!((w[i][j] - p[i][j]).abs() < 1e-6, "{} vs {}", w[i][j], p[i][j]);
            }
        }
        // Points too.
        let x = [p[0][3] + 1.234567, p[1][3] - 7.654321, p[2][3] + 0.5];
        let y = tf.to_world(tf.to_normalized(x));
        for i in 0..3 {
            assert!((x[i] - y[i]).abs() < 1e-6);
        }
    }
    assert!((max_abs - 1.0).abs() < 1e-12, "centres fill [-1,1]^3 in L∞: {max_abs}");
    // Mean up maps to +Z.
    let mut up = [0.0; 3];
    for p in &poses {
        let n = tf.pose_to_normalized(p);
        for i in 0..3 {
            up[i] += n[i][1];
        }
    }
    let nu = (up[0] * up[0] + up[1] * up[1] + up[2] * up[2]).sqrt();
    assert!((up[2] / nu - 1.0).abs() < 1e-9);
}

fn cam(model: CameraModel, d: Distortion) -> Camera {
    Camera { model, fx: 500.0, fy: 400.0, cx: 320.0, cy: 240.0, width: 640, height: 480, distortion: d }
}

#[test]
fn pinhole_rays_match_hand_computed_directions() {
    let c = cam(CameraModel::Pinhole, Distortion::default());
    let id = pose([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [10.0, 20.0, 30.0]);
    // Pixel (row 239, col 319): centre (319.5, 239.5) → x = −0.5/500, y = −0.5/400 → GL (x, −y, −1).
    let r = c.ray_f64(&id, 239, 319);
    let d: [f64; 3] = [-0.001, 0.00125, -1.0];
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    for i in 0..3 {
        assert!((r.direction[i] - d[i] / n).abs() < 1e-12);
    }
    assert!((r.direction_norm - n).abs() < 1e-12);
    assert_eq!(r.origin, [10.0, 20.0, 30.0]);
    // Corner pixel (0, 0) with a 90° yaw about +Z: camera x → world y.
    let rz = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
    let r = c.ray_f64(&pose(rz, [0.0; 3]), 0, 0);
    let (x, y) = ((0.5 - 320.0) / 500.0, -(0.5 - 240.0) / 400.0);
    let w = [-y, x, -1.0];
    let n = (x * x + y * y + 1.0f64).sqrt();
    for i in 0..3 {
        assert!((r.direction[i] - w[i] / n).abs() < 1e-12);
    }
    // f32 twin agrees.
    let c2w32 = [[0.0f32, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let r32 = c.ray_f32(&c2w32, 0, 0);
    for i in 0..3 {
        assert!((r32.direction[i] as f64 - r.direction[i]).abs() < 1e-6);
    }
}

#[test]
fn undistort_inverts_distort_over_a_grid() {
    let d = Distortion { k1: -0.1, k2: 0.05, k3: -0.01, k4: 0.002, p1: 0.001, p2: -0.0005 };
    let p64 = d.params::<f64>();
    let p32 = d.params::<f32>();
    for i in -10..=10 {
        for j in -10..=10 {
            let (x, y) = (i as f64 * 0.06, j as f64 * 0.045);
            let (xd, yd) = distort(x, y, &p64);
            let (ux, uy) = undistort(xd, yd, &p64);
            assert!((ux - x).abs() < 1e-6 && (uy - y).abs() < 1e-6, "({x},{y}) → ({ux},{uy})");
            let (xd32, yd32) = distort(x as f32, y as f32, &p32);
            let (ux32, uy32) = undistort(xd32, yd32, &p32);
            assert!((ux32 as f64 - x).abs() < 1e-5 && (uy32 as f64 - y).abs() < 1e-5);
        }
    }
    // Through the camera: the ray of a distorted pixel points at the undistorted normalised point.
    let c = cam(CameraModel::OpenCv, d);
    let id = pose([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [0.0; 3]);
    let r = c.ray_f64(&id, 10, 600);
    let (ux, uy) = undistort((600.5 - 320.0) / 500.0, (10.5 - 240.0) / 400.0, &p64);
    let n = (ux * ux + uy * uy + 1.0f64).sqrt();
    assert!((r.direction[0] - ux / n).abs() < 1e-12 && (r.direction[1] + uy / n).abs() < 1e-12);
}

#[test]
fn fisheye_direction_uses_theta() {
    let c = cam(CameraModel::OpenCvFisheye, Distortion::default());
    let id = pose([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [0.0; 3]);
    let r = c.ray_f64(&id, 239, 569); // x = (569.5 − 320)/500 = 0.499, y = −0.5/400
    let (x, y) = (249.5 / 500.0, -(-0.5f64 / 400.0));
    let th = (x * x + y * y).sqrt();
    let e = [x * th.sin() / th, y * th.sin() / th, -th.cos()];
    for i in 0..3 {
        assert!((r.direction[i] - e[i]).abs() < 1e-12);
    }
    assert!((r.direction_norm - 1.0).abs() < 1e-12);
}

/// The aerial normalisation (issue 18) on the built-in scenes' camera layouts, with UTM offsets: the ground
/// (z = world_offset z) must land at normalised z = -0.5 within 2 % of the cube, the ground the cameras look at
/// inside the cube, and the up axis stays vertical; a forward-looking rig and a nadir grid fall back (an error
/// naming why).
#[test]
fn aerial_normalisation_puts_the_ground_at_minus_one_half() {
    use msnerf::data::aerial::{normalize_poses_aerial, NotAerial};
    use msnerf::sim::{cameras, SceneDesc};
    for name in ["campus", "ci-small"] {
        let scene = SceneDesc::load(name).expect("scene");
        let off = scene.world_offset;
        let cam = cameras::intrinsics(scene.image.width, scene.image.height, scene.image.hfov_deg);
        let poses: Vec<Mat4> = cameras::scene_poses(&scene, None)
            .expect("poses")
            .into_iter()
            .map(|mut p| {
                for i in 0..3 {
                    p[i][3] += off[i];
                }
                p
            })
            .collect();
        let frames: Vec<(Mat4, Camera)> = poses.iter().map(|p| (*p, cam)).collect();
        let t = normalize_poses_aerial(&frames).expect("an aerial layout");
        // Ground points below the cameras' look-at points.
        for q in [[0.0, 0.0], [10.0, -5.0], [-12.0, 7.0]] {
            let g = t.to_normalized([off[0] + q[0], off[1] + q[1], off[2]]);
            assert!((g[2] + 0.5).abs() < 0.02, "{name}: ground at normalised z {}", g[2]);
            assert!(g[0].abs() < 1.0 && g[1].abs() < 1.0, "{name}: ground point {g:?} inside the cube");
        }
        // Vertical stays vertical: a 10 m mast maps to a vertical segment.
        let a = t.to_normalized([off[0], off[1], off[2]]);
        let b = t.to_normalized([off[0], off[1], off[2] + 10.0]);
        assert!((a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9, "{name}: up axis kept");
        // The round trip is exact to a micrometre at UTM offsets.
        let w = t.to_world(t.to_normalized([off[0] + 3.0, off[1] - 4.0, off[2] + 5.0]));
        assert!((w[0] - off[0] - 3.0).abs() < 1e-6 && (w[2] - off[2] - 5.0).abs() < 1e-6, "{w:?}");
    }
    let cam = cameras::intrinsics(64, 48, 49.6);
    // A rig looking at the horizon.
    let level: Vec<(Mat4, Camera)> =
        (0..8).map(|i| (pose(rot(0.0, i as f64 * 0.7), [i as f64, 0.0, 2.0]), cam)).collect();
    assert!(matches!(normalize_poses_aerial(&level), Err(NotAerial::NotLookingDown(_))));
    // A nadir grid: parallel axes never meet (and the mean camera-up is horizontal, as for nerfstudio's `up`).
    let nadir: Vec<(Mat4, Camera)> =
        (0..16).map(|i| (pose(rot(0.0, 0.0), [(i % 4) as f64 * 10.0, (i / 4) as f64 * 10.0, 50.0]), cam)).collect();
    assert!(normalize_poses_aerial(&nadir).is_err());
    // Oblique cameras all looking the same way: their axes are parallel.
    let parallel: Vec<(Mat4, Camera)> =
        (0..16).map(|i| (pose(rot(0.6, 0.0), [(i % 4) as f64 * 10.0, (i / 4) as f64 * 10.0, 50.0]), cam)).collect();
    let e = normalize_poses_aerial(&parallel).expect_err("parallel axes");
    assert!(matches!(e, NotAerial::AxesDoNotMeet(_) | NotAerial::NotLookingDown(_)), "{e}");
}

/// The export's projection (`data::camera::project_point`) inverts ray generation for every camera model: the ray
/// through the centre of pixel (row, col), followed for t, projects back to (row, col) at distance t.
#[test]
fn projection_inverts_ray_generation() {
    use msnerf::data::camera::project_point;
    let dist = Distortion { k1: -0.12, k2: 0.03, k3: 0.0, k4: 0.0, p1: 0.001, p2: -0.0005 };
    let fisheye = Distortion { k1: 0.05, k2: -0.01, k3: 0.0, k4: 0.0, p1: 0.0, p2: 0.0 };
    let c2w = pose(rot(0.4, -0.7), [3.0, -2.0, 7.0]);
    let rows = [0, 1, 2].map(|r| [c2w[r][0], c2w[r][1], c2w[r][2]]);
    for (model, d) in [
        (CameraModel::Pinhole, Distortion::default()),
        (CameraModel::OpenCv, dist),
        (CameraModel::OpenCvFisheye, fisheye),
        (CameraModel::Orthographic, Distortion::default()),
    ] {
        let c = cam(model, d);
        for (row, col) in [(0u32, 0u32), (5, 17), (c.height / 2, c.width / 2), (c.height - 1, c.width - 1)] {
            let ray = c.ray_f64(&c2w, row, col);
            for t in [0.5, 5.0, 40.0] {
                let p = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k]);
                let (r2, c2, d2) = project_point(&c, [c2w[0][3], c2w[1][3], c2w[2][3]], &rows, p)
                    .unwrap_or_else(|| panic!("{model:?} ({row}, {col}) t {t}: not projected"));
                assert_eq!((r2, c2), (row, col), "{model:?} t {t}");
                assert!((d2 - t).abs() < 1e-9 * t.max(1.0), "{model:?}: distance {d2} want {t}");
            }
        }
        // Behind a pinhole or orthographic camera: nothing.
        if matches!(model, CameraModel::Pinhole | CameraModel::Orthographic) {
            let ray = c.ray_f64(&c2w, 3, 3);
            let p = [0, 1, 2].map(|k| ray.origin[k] - 5.0 * ray.direction[k]);
            assert!(project_point(&c, [c2w[0][3], c2w[1][3], c2w[2][3]], &rows, p).is_none());
        }
    }
}
