//! Geometry of the simulator, checked through the data loader: every depth back-projects onto the scene's
//! analytic surfaces, poses follow the flight plan, intrinsics are the MS600Pro's, and the ground-truth point
//! cloud lies on the surfaces with the materials' band reflectances.

use crate::sim_support;
use msnerf::data::check_dataset;
use sim_support::*;

const OFFSET: [f64; 3] = [500000.0, 4000000.0, 20.0];

fn scene_yaml() -> String {
    format!(
        "name: geo\nworld_offset: [{}, {}, {}]\nimage: {{width: 80, height: 60}}\n{MATERIALS}\n\
ground: {{material: panel, extent: 400}}\n\
regions:\n  - {{material: dark, rect: {{center: [0, -8], size: [40, 3], yaw_deg: 10}}}}\n\
water:\n  - {{material: dark, polygon: [[-12, 5], [-6, 6], [-7, 12], [-12, 11]]}}\n\
boxes:\n  - {{center: [6, 4], size: [8, 6, 7], yaw_deg: 20, material: wall, roof: roof}}\n\
trees:\n  - {{position: [-6, -2], trunk_height: 2.0, trunk_radius: 0.3, crown: [2.5, 2.0, 1.5], crown_material: leaves, trunk_material: bark}}\n\
cameras:\n  - orbit: {{center: [0, 0], radius: 23, height: 40, tilt_deg: -60, count: 6}}\n  - grid: {{center: [0, 0], size: [20, 10], height: 30, rows: 2, cols: 2}}\n  - poses:\n      - {{position: [-15, -3, 2.5], look_at: [-6, -2, 2.5]}}\n",
        OFFSET[0], OFFSET[1], OFFSET[2]
    )
}

/// Distance from local point `p` to the nearest analytic surface of `scene_yaml`'s scene.
fn surface_distance(p: [f64; 3]) -> f64 {
    let mut d = p[2].abs(); // ground
                            // Box: yaw 20 about (6, 4), half sizes (4, 3, 3.5) about mid-height.
    let (s, c) = 20f64.to_radians().sin_cos();
    let (dx, dy) = (p[0] - 6.0, p[1] - 4.0);
    let l = [c * dx + s * dy, -s * dx + c * dy, p[2] - 3.5];
    let q = [l[0].abs() - 4.0, l[1].abs() - 3.0, l[2].abs() - 3.5];
    let outside = q.iter().map(|x| x.max(0.0).powi(2)).sum::<f64>().sqrt();
    let inside = q[0].max(q[1]).max(q[2]).min(0.0);
    d = d.min((outside + inside).abs());
    // Crown: ellipsoid at (-6, -2, 3.5) with semi-axes (2.5, 2, 1.5): |q| − 1 scaled by the smallest axis.
    let e = [(p[0] + 6.0) / 2.5, (p[1] + 2.0) / 2.0, (p[2] - 3.5) / 1.5];
    d = d.min(((e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt() - 1.0).abs() * 1.5);
    // Trunk: radius 0.3, z in [0, 2], capped.
    let rr = (p[0] + 6.0).hypot(p[1] + 2.0);
    if (0.0..=2.0).contains(&p[2]) {
        d = d.min((rr - 0.3).abs());
    }
    if rr <= 0.3 {
        d = d.min((p[2] - 2.0).abs());
    }
    // Backdrop dome, radius 400 about the origin.
    d.min(((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 400.0).abs())
}

#[test]
fn depth_back_projects_onto_the_analytic_surfaces() {
    let (_t, ds) = run_yaml(&scene_yaml());
    assert_eq!(ds.frames.len(), 11);
    assert!(!ds.depth_is_z);
    assert_eq!(ds.depth_unit_scale_factor, 1.0);
    let mut worst = 0f64;
    let mut kinds = [0usize; 3]; // ground, above ground, far
    for (i, fr) in ds.frames.iter().enumerate() {
        let depth = ds.read_depth(i).unwrap().expect("every frame has depth");
        for row in 0..ds.height {
            for col in 0..ds.width {
                let ray = fr.camera.ray_f64(&fr.c2w, row, col);
                let t = depth[(row * ds.width + col) as usize] as f64;
                assert!(t.is_finite() && t > 0.0);
                let p = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k] - OFFSET[k]);
                let d = surface_distance(p);
                assert!(d < 1e-4, "frame {i} ({row},{col}): {p:?} is {d} m off every surface");
                worst = worst.max(d);
                kinds[if p[2].abs() < 1e-4 {
                    0
                } else if t < 300.0 {
                    1
                } else {
                    2
                }] += 1;
            }
        }
    }
    assert!(kinds[0] > 1000 && kinds[1] > 1000, "ground and objects both seen: {kinds:?}");
    eprintln!("worst back-projection error {worst:.2e} m, {kinds:?}");
    let rep = check_dataset(&ds.root, 1 << 30);
    assert!(rep.is_ok(), "{:?}", rep.errors);
    assert_eq!(rep.frames, 11);
}

#[test]
fn poses_follow_the_flight_plan_and_intrinsics_are_ms600pro() {
    let (_t, ds) = run_yaml(&scene_yaml());
    let hfov = 49.6f64.to_radians();
    for fr in &ds.frames {
        let c = &fr.camera;
        assert_eq!((c.width, c.height), (80, 60));
        assert!((c.fx - 40.0 / (hfov / 2.0).tan()).abs() < 1e-9 && c.fx == c.fy);
        assert_eq!((c.cx, c.cy), (40.0, 30.0));
        // Rotation orthonormal, right-handed.
        let m = fr.c2w;
        for a in 0..3 {
            for b in 0..3 {
                let d: f64 = (0..3).map(|k| m[k][a] * m[k][b]).sum();
                assert!((d - f64::from(u8::from(a == b))).abs() < 1e-12);
            }
        }
    }
    // Orbit views (frames 0-5, names sort in write order): on the circle, looking at -60 degrees, at the centre.
    for fr in &ds.frames[..6] {
        let m = fr.c2w;
        let (x, y, z) = (m[0][3] - OFFSET[0], m[1][3] - OFFSET[1], m[2][3] - OFFSET[2]);
        assert!((x.hypot(y) - 23.0).abs() < 1e-9 && (z - 40.0).abs() < 1e-9);
        let fwd = [-m[0][2], -m[1][2], -m[2][2]];
        assert!((fwd[2].asin().to_degrees() + 60.0).abs() < 1e-9);
        // Heading towards the centre, image x axis horizontal.
        assert!((fwd[0] * x + fwd[1] * y) / x.hypot(y) / fwd[0].hypot(fwd[1]) < -1.0 + 1e-12);
        assert!(m[2][0].abs() < 1e-12);
    }
    // Grid views: nadir, at 30 m, on the 20 x 10 rectangle corners.
    for fr in &ds.frames[6..10] {
        let m = fr.c2w;
        assert!((m[2][2] - 1.0).abs() < 1e-12, "looking straight down");
        let (x, y) = (m[0][3] - OFFSET[0], m[1][3] - OFFSET[1]);
        assert!(((x.abs() - 10.0).abs() < 1e-9) && ((y.abs() - 5.0).abs() < 1e-9), "{x} {y}");
    }
}

/// Reads `ground_truth.ply` with the project's PLY reader: (header lines, xyz, per-band values).
fn read_ply(path: &std::path::Path) -> (Vec<String>, Vec<[f64; 3]>, Vec<Vec<f32>>) {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header: Vec<String> = String::from_utf8(bytes[..end].to_vec()).unwrap().lines().map(String::from).collect();
    let cloud = msnerf::output::pointcloud::read_ply(path).unwrap();
    let b = cloud.bands.len();
    let vals = cloud.values.chunks(b).map(|c| c.to_vec()).collect();
    (header, cloud.positions, vals)
}

#[test]
fn ground_truth_points_lie_on_surfaces_with_band_reflectance() {
    let (_t, ds) = run_yaml(&scene_yaml());
    let (header, xyz, vals) = read_ply(&ds.root.join("ground_truth.ply"));
    assert!(header.contains(&"format binary_little_endian 1.0".to_string()));
    for (name, c) in [
        ("refl_450", 450),
        ("refl_555", 555),
        ("refl_660", 660),
        ("refl_720", 720),
        ("refl_750", 750),
        ("refl_840", 840),
    ] {
        assert!(header.contains(&format!("property float {name}")), "{name}");
        assert!(
            header.iter().any(|l| l.starts_with("comment band ") && l.contains(&format!("center_nm {c} fwhm_nm "))),
            "{name}"
        );
    }
    // A world offset makes x y z double (float cannot hold UTM coordinates to a millimetre).
    assert!(header.contains(&"property double x".to_string()));
    assert!(xyz.len() > 10_000, "{}", xyz.len());
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ds.root.join("simulation.json")).unwrap()).unwrap();
    let mats: Vec<Vec<f32>> = meta["materials"]
        .as_object()
        .unwrap()
        .values()
        .map(|m| m["band_reflectance"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect())
        .collect();
    for (p, v) in xyz.iter().zip(&vals) {
        let local = [0, 1, 2].map(|k| p[k] - OFFSET[k]);
        assert!(surface_distance(local) < 1e-4, "{local:?}");
        assert!(local.iter().map(|x| x * x).sum::<f64>().sqrt() < 399.0, "no backdrop points");
        assert!(mats.contains(v), "{v:?} is some material's band reflectance");
    }
    // Flat materials read their value in every band.
    assert!(vals.iter().any(|v| v.iter().all(|&x| x == 0.4)));
    assert!(vals.iter().any(|v| v.iter().all(|&x| x == 0.3)), "roof points");
}

#[test]
fn builtin_scenes_load_and_pass_check_dataset() {
    for name in ["ci-small", "campus"] {
        let desc = msnerf::sim::SceneDesc::load(name).unwrap();
        let opts = msnerf::sim::SimOptions { width: Some(48), views: Some(8), ..Default::default() };
        let (_t, ds) = run(&desc, &opts);
        assert_eq!((ds.width, ds.height, ds.frames.len(), ds.n_bands()), (48, 36, 8, 6), "{name}");
        let rep = check_dataset(&ds.root, 1 << 30);
        assert!(rep.is_ok(), "{name}: {:?}", rep.errors);
        // Reflectances are plausible: within [0, 1.5] (sunlit walls may exceed 1 slightly).
        for b in &rep.bands {
            assert!(b.min.unwrap() >= 0.0 && b.max.unwrap() < 1.5, "{name} {b:?}");
        }
        // Pose normalisation sees the UTM-sized offset and brings it to the unit cube.
        let pt = ds.pose_transform();
        let n = pt.to_normalized([ds.frames[0].c2w[0][3], ds.frames[0].c2w[1][3], ds.frames[0].c2w[2][3]]);
        assert!(n.iter().all(|x| x.abs() <= 1.0 + 1e-9), "{n:?}");
    }
}
