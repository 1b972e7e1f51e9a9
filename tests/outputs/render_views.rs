//! Novel views on the simulated `ci-small` scene: the orbit's defaults recover the simulated flight, camera paths in
//! both formats render exactly like the dataset frame they reproduce (nerfstudio's path in the normalised frame,
//! transforms.json-style frames in the world frame), `msnerf render --views orbit|PATH.json` writes its files, and
//! bad paths or flags fail naming the file, key and index without touching the output folder.

use crate::common;
use common::{gpu, TempDir};
use msnerf::data::{load_dataset, LoadOptions, Split};
use msnerf::nerf::camera_path::load_camera_path;
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::run::LoadedRun;
use msnerf::nerf::trainer::train;
use msnerf::nerf::views::{orbit_frame, NovelView};
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use serde_json::json;
use std::path::Path;

fn dataset(dir: &Path) {
    let scene = SceneDesc::load("ci-small").expect("built-in scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

fn train_briefly(data: &Path, out: &Path) {
    let g = gpu();
    let mut model = ModelConfig::resolve("tiny").expect("tiny");
    model.trainer.max_steps = 5;
    model.trainer.steps_per_eval = 1000;
    model.trainer.steps_per_save = 1000;
    train(&g, &common::train_options(data, out, model, 256)).expect("train");
}

fn msnerf(args: &[&str]) -> (bool, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf")).args(args).output().expect("run msnerf");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr))
}

fn gdal_size_and_bands(tif: &Path) -> (u64, u64, usize) {
    let info = std::process::Command::new("gdalinfo")
        .arg("-json")
        .arg(tif)
        .output()
        .expect("gdalinfo is needed to check GeoTIFFs: run `bash tools/setup-debian.sh` (installs gdal-bin)");
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).expect("gdalinfo json");
    let size = v["size"].as_array().expect("size");
    (size[0].as_u64().expect("w"), size[1].as_u64().expect("h"), v["bands"].as_array().expect("bands").len())
}

#[test]
fn orbit_defaults_recover_the_simulated_flight() {
    // ci-small: 12 cameras on a circle of radius 23 m at 40 m, tilted -60 degrees, around the local origin, which
    // sits at world (500000, 4000000, 20). At -60 degrees from 40 m they look at a point 40/tan(60) = 23.1 m away
    // horizontally: the orbit centre on the ground, to 0.1 m.
    let tmp = TempDir::new("orbit_frame");
    dataset(&tmp.path().join("data"));
    let ds = load_dataset(&tmp.path().join("data"), &LoadOptions::default()).expect("dataset");
    let t = ds.pose_transform();
    let poses: Vec<_> =
        ds.split_indices(Split::Train).iter().map(|&f| t.pose_to_normalized(&ds.frames[f].c2w)).collect();
    let of = orbit_frame(&poses).expect("orbit");
    let c = t.to_world(of.centre);
    assert!((c[0] - 500000.0).abs() < 0.5 && (c[1] - 4000000.0).abs() < 0.5 && (c[2] - 20.0).abs() < 0.5, "{c:?}");
    assert!((of.radius / t.scale - 23.0).abs() < 0.5, "radius {} m", of.radius / t.scale);
    assert!((of.height / t.scale - 40.0).abs() < 0.5, "height {} m", of.height / t.scale);
}

#[test]
fn camera_path_errors_name_the_file_key_and_index() {
    let tmp = TempDir::new("path_errors");
    dataset(&tmp.path().join("data"));
    let ds = load_dataset(&tmp.path().join("data"), &LoadOptions::default()).expect("dataset");
    let t = ds.pose_transform();
    let eye: Vec<f64> = vec![1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.];
    let cases = [
        (
            json!({"camera_path": [{"camera_to_world": eye, "fov": 50}, {"fov": 50}]}),
            "camera_path[1]: key `camera_to_world` missing",
        ),
        (
            json!({"camera_path": [{"camera_to_world": [1, 2, 3], "fov": 50}]}),
            "camera_path[0].camera_to_world: expected 16 numbers",
        ),
        (json!({"camera_path": [{"camera_to_world": eye, "fov": 200}]}), "camera_path[0].fov"),
        (json!({"camera_path": [{"camera_to_world": eye}], "render_width": 0}), "render_width"),
        (json!({"camera_path": [{"camera_to_world": eye}], "camera_type": "fisheye"}), "camera_type"),
        (json!({"camera_path": []}), "camera_path: the list is empty"),
        (json!([{"transform_matrix": eye}, {"file_path": "x.tif"}]), "[1]: key `transform_matrix` missing"),
        (
            json!({"frames": [{"transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]}]}),
            "frames[0].transform_matrix: the 3x3 rotation part is singular",
        ),
        (
            json!({"frames": [{"transform_matrix": [[1, 0, 0, "a"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}]}),
            "element 3 is not a finite number",
        ),
        (json!({"cameras": []}), "expected nerfstudio's camera path"),
    ];
    for (k, (j, want)) in cases.iter().enumerate() {
        let p = tmp.path().join(format!("bad{k}.json"));
        std::fs::write(&p, j.to_string()).expect("write");
        let e = load_camera_path(&p, &ds, &t).expect_err("must fail").to_string();
        assert!(e.contains(&format!("bad{k}.json")) && e.contains(want), "case {k}: {e}");
    }
    let p = tmp.path().join("broken.json");
    std::fs::write(&p, "{\"camera_path\": [").expect("write");
    let e = load_camera_path(&p, &ds, &t).expect_err("must fail").to_string();
    assert!(e.contains("broken.json") && e.contains("not valid JSON"), "{e}");
}

#[test]
fn novel_views_render_like_the_frames_they_reproduce_and_through_the_cli() {
    let tmp = TempDir::new("novel_views");
    let (data, run_dir) = (tmp.path().join("data"), tmp.path().join("run"));
    dataset(&data);
    train_briefly(&data, &run_dir);
    let ds = load_dataset(&data, &LoadOptions::default()).expect("dataset");
    let t = ds.pose_transform();
    let f0 = &ds.frames[0];
    // Frame 0 as nerfstudio's viewer would save it: normalised pose, row-major, vertical FOV in degrees.
    let n = t.pose_to_normalized(&f0.c2w);
    let flat: Vec<f64> = n.iter().flatten().copied().collect();
    let fov = 2.0 * (f0.camera.height as f64 / (2.0 * f0.camera.fy)).atan().to_degrees();
    let ns_path = tmp.path().join("camera_path.json");
    let (w, h) = (f0.camera.width, f0.camera.height);
    let ns = json!({"render_width": w, "render_height": h, "camera_type": "perspective",
                    "camera_path": [{"camera_to_world": flat, "fov": fov, "aspect": w as f64 / h as f64}]});
    std::fs::write(&ns_path, ns.to_string()).expect("write");
    // Frame 0 as a transforms.json-style frame: world pose, 4x4 rows.
    let tf_path = tmp.path().join("frames.json");
    std::fs::write(&tf_path, json!([{"transform_matrix": f0.c2w}]).to_string()).expect("write");

    {
        let g = gpu();
        let mut run = LoadedRun::load(&g, &run_dir).expect("run");
        let frame = run.render_view(0).expect("frame 0");
        for (path, tol) in [(&tf_path, 0.0), (&ns_path, 1e-4)] {
            let views = load_camera_path(path, &run.ds, &run.transform).expect("path");
            run.set_novel_views(&views).expect("camera table");
            let v = run.render_novel_view(0).expect("novel view");
            assert_eq!((v.width, v.height, v.frame), (frame.width, frame.height, run.ds.frames.len()));
            let worst = v.colour.iter().zip(&frame.colour).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(worst <= tol, "{}: frame 0 reproduced within {tol}: worst band difference {worst}", path.display());
            let dd = v.depth.iter().zip(&frame.depth).map(|(a, b)| (a - b).abs() / b.max(1e-3)).fold(0.0f32, f32::max);
            assert!(dd <= 1e-3 + tol * 10.0, "depth relative difference {dd}");
        }
        // Control: another frame's pose renders visibly differently, so the comparisons above can fail.
        let f1 = &run.ds.frames[1];
        let other = vec![NovelView {
            name: "control".into(),
            camera: f1.camera,
            c2w: run.transform.pose_to_normalized(&f1.c2w),
        }];
        run.set_novel_views(&other).expect("camera table");
        let v = run.render_novel_view(0).expect("control view");
        let worst = v.colour.iter().zip(&frame.colour).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst > 1e-2, "frames 0 and 1 differ: worst band difference {worst}");
        // The dataset's frames still render as before once novel views are in the table.
        let again = run.render_view(0).expect("frame 0 again");
        assert_eq!(again.colour, frame.colour);
    }

    let r = run_dir.to_str().expect("utf-8");
    let out = tmp.path().join("orbit");
    let (ok, text) =
        msnerf(&["render", r, "--views", "orbit", "--orbit-views", "2", "--out", out.to_str().expect("utf-8")]);
    assert!(ok, "{text}");
    for k in 0..2 {
        let tif = out.join(format!("orbit_{k:03}.tif"));
        assert_eq!(gdal_size_and_bands(&tif), (w as u64, h as u64, 6), "{}", tif.display());
        for suffix in ["_rgb.png", "_ndvi.tif", "_depth.png", "_acc.png"] {
            assert!(out.join(format!("orbit_{k:03}{suffix}")).is_file(), "orbit_{k:03}{suffix}");
        }
        assert!(!out.join(format!("orbit_{k:03}_error.png")).exists(), "novel views have no ground truth");
    }
    assert!(out.join("contact_sheet.png").is_file());

    // nerfstudio's path at its own size.
    let small = tmp.path().join("small_path.json");
    let mut s = ns.clone();
    s["render_width"] = json!(40);
    s["render_height"] = json!(30);
    std::fs::write(&small, s.to_string()).expect("write");
    let out = tmp.path().join("path");
    let (ok, text) =
        msnerf(&["render", r, "--views", small.to_str().expect("utf-8"), "--out", out.to_str().expect("utf-8")]);
    assert!(ok, "{text}");
    assert_eq!(gdal_size_and_bands(&out.join("path_000.tif")), (40, 30, 6));

    // Errors: named, and nothing written.
    let bad = tmp.path().join("bad_path.json");
    std::fs::write(&bad, json!({"camera_path": [{"camera_to_world": flat, "fov": 40}, {"fov": 40}]}).to_string())
        .expect("write");
    let none = tmp.path().join("not_written");
    let o = none.to_str().expect("utf-8");
    for (args, want) in [
        (vec!["--views", bad.to_str().expect("utf-8")], "bad_path.json: camera_path[1]: key `camera_to_world` missing"),
        (vec!["--views", "sideways"], "--views sideways: expected eval, train, all, orbit"),
        (vec!["--views", "eval", "--orbit-views", "3"], "need --views orbit"),
        (vec!["--views", "orbit", "--orbit-views", "0"], "--orbit-views: must be 1..=100000, got 0"),
        (vec!["--views", "orbit", "--orbit-views", "100001"], "--orbit-views: must be 1..=100000, got 100001"),
        (vec!["--views", "orbit", "--orbit-pitch-deg", "-95"], "--orbit-pitch-deg"),
    ] {
        let mut a = vec!["render", r, "--out", o];
        a.extend(args);
        let (ok, text) = msnerf(&a);
        assert!(!ok && text.contains(want), "{a:?}: {text}");
        assert!(!text.contains("panicked"), "{text}");
        assert!(!none.exists(), "a failed render leaves no output folder");
    }
}
