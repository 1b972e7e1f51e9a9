//! The written dataset: determinism (seed, thread count), layouts (multi-band, band files, u16), any number of
//! bands, atomic writing, and errors that name the scene file and key (library and `msnerf simulate`).

use crate::sim_support;
use msnerf::sim::{simulate, PixelFormat, SceneDesc, SimOptions};
use sim_support::*;

fn noisy_ci() -> SceneDesc {
    let mut d = SceneDesc::load("ci-small").unwrap();
    let extra: SceneDesc = scene(
        "name: x\nmaterials: {a: {flat: 0.1}}\nground: {material: a}\ncameras: [{orbit: {center: [0, 0], radius: 1, height: 10, count: 1}}]\n\
effects:\n  sun: {azimuth_deg: 135, elevation_deg: 40}\n  vegetation_brdf: {}\n  misregistration: {bands: [{band: red, shift_px: [0.5, 0.25], rotation_deg: 0.3}]}\n  vignetting: {coeffs: [-0.2]}\n  exposure_drift: {std: 0.03, band_std: 0.01}\n  noise: {std: 0.005, shot: 0.0001}\n",
    );
    d.effects = extra.effects;
    d
}

#[test]
fn same_seed_same_bytes_at_any_thread_count() {
    let d = noisy_ci();
    let t = TempDir::new("det");
    let go = |name: &str, threads: usize, seed: Option<u64>| {
        let out = t.path().join(name);
        let opts = SimOptions { threads, seed, ..Default::default() };
        let rep = simulate(&d, &opts, &out).unwrap();
        assert_eq!(rep.effects.len(), 6);
        files(&out)
    };
    let a = go("a", 1, None);
    let b = go("b", 2, None);
    let c = go("c", 3, None);
    let e = go("e", 2, Some(99));
    assert!(a.len() > 20);
    assert!(a == b, "1 vs 2 threads");
    assert!(a == c, "1 vs 3 threads");
    let differ: Vec<&String> = a.iter().zip(&e).filter(|(x, y)| x.1 != y.1).map(|(x, _)| &x.0).collect();
    assert!(differ.iter().any(|n| n.starts_with("images/")), "another seed changes the noise");
    assert!(!differ.iter().any(|n| n.starts_with("depth/")), "but not the geometry");
    // No staging folders are left behind.
    let left: Vec<_> = std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 4, "{left:?}");
}

#[test]
fn band_files_and_u16_layouts_load_to_the_same_values() {
    let d = SceneDesc::load("ci-small").unwrap();
    let (_a, multi) = run(&d, &SimOptions::default());
    let (_b, rig) = run(&d, &SimOptions { band_files: true, ..Default::default() });
    let (_c, u16s) = run(&d, &SimOptions { format: PixelFormat::U16, ..Default::default() });
    assert!(matches!(rig.frames[0].image, msnerf::data::ImageSource::BandFiles(ref f) if f.len() == 6));
    assert_eq!(u16s.pixel_scale, Some(msnerf::sim::U16_SCALE));
    for i in [0, 5, 11] {
        let (m, r, u) = (frame(&multi, i), frame(&rig, i), frame(&u16s, i));
        for row in 0..multi.height {
            for col in 0..multi.width {
                for b in 0..6 {
                    assert_eq!(m.get(row, col, b), r.get(row, col, b));
                    assert!((m.get(row, col, b) - u.get(row, col, b)).abs() <= 0.5 / 32767.5 + 1e-7);
                }
            }
        }
    }
    assert!(msnerf::data::check_dataset(&rig.root, 1 << 30).is_ok());
}

#[test]
fn any_number_of_bands() {
    for (bands, n) in [
        ("band_range: {start_nm: 400, end_nm: 900, count: 128, fwhm_nm: 5}\n", 128),
        ("bands:\n  - {name: r, center_nm: 660, fwhm_nm: 20}\n  - {name: g, center_nm: 555, fwhm_nm: 20}\n  - {name: b, center_nm: 450, response: [[430, 0], [450, 1], [470, 0]]}\n", 3),
    ] {
        let yaml = panel_scene(16, 12, "").replace("name: panel\n", &format!("name: panel\n{bands}"));
        let yaml = yaml.replace("ground: {material: panel", "ground: {material: leaves");
        let (_t, ds) = run_yaml(&yaml);
        assert_eq!(ds.n_bands(), n);
        let img = frame(&ds, 0);
        assert_eq!(img.bands, n);
        let (header, _) = std::fs::read(ds.root.join("ground_truth.ply")).map(|b| {
            let s = String::from_utf8_lossy(&b[..b.windows(10).position(|w| w == b"end_header").unwrap()]).into_owned();
            (s, ())
        }).unwrap();
        assert_eq!(header.matches("property float refl_").count(), n);
        if n == 128 {
            // The leaves' red edge across the hyperspectral bands: low near 660 nm, high near 850 nm.
            let at = |nm: f64| ds.bands.iter().position(|b| (b.center_nm.unwrap() - nm).abs() < 2.0).unwrap();
            assert!(img.get(3, 3, at(850.0)) > 5.0 * img.get(3, 3, at(660.0)));
        }
    }
}

#[test]
fn existing_output_is_never_touched_and_errors_leave_nothing() {
    let t = TempDir::new("atomic");
    let out = t.path().join("ds");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), b"mine").unwrap();
    let d = SceneDesc::load("ci-small").unwrap();
    let e = simulate(&d, &SimOptions::default(), &out).unwrap_err().to_string();
    assert!(e.contains("already exists") && e.contains("--overwrite"), "{e}");
    assert_eq!(std::fs::read(out.join("keep.txt")).unwrap(), b"mine");
    // A bad option fails before anything is written.
    let e = simulate(&d, &SimOptions { views: Some(0), ..Default::default() }, &t.path().join("x")).unwrap_err();
    assert!(e.to_string().contains("--views"), "{e}");
    // --overwrite replaces the folder as a whole.
    simulate(&d, &SimOptions { overwrite: true, ..Default::default() }, &out).unwrap();
    assert!(!out.join("keep.txt").exists() && out.join("transforms.json").is_file());
    let names: Vec<String> =
        std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(names, vec!["ds".to_string()], "no staging folders left");
}

#[test]
fn views_option_sets_the_orbit_count() {
    let d = SceneDesc::load("campus").unwrap();
    let (_t, ds) = run(&d, &SimOptions { views: Some(10), width: Some(32), points: 1000, ..Default::default() });
    assert_eq!(ds.frames.len(), 10);
    let ply = std::fs::read(ds.root.join("ground_truth.ply")).unwrap();
    let end = ply.windows(10).position(|w| w == b"end_header").unwrap();
    let head = String::from_utf8_lossy(&ply[..end]).into_owned();
    let n: usize = head.lines().find_map(|l| l.strip_prefix("element vertex ")).unwrap().parse().unwrap();
    assert!((900..=1100).contains(&n), "{n} points for a target of 1000");
}

fn err(yaml: &str) -> String {
    SceneDesc::from_yaml(yaml, "scenes/bad.yaml").unwrap_err().to_string()
}

#[test]
fn bad_scenes_name_the_file_and_key() {
    let good = panel_scene(8, 6, "");
    assert!(SceneDesc::from_yaml(&good, "ok.yaml").is_ok());
    let cases = [
        (good.replace("ground: {material: panel", "ground: {materal: panel"), "materal"),
        (good.replace("name: panel\n", "name: panel\nimage_size: 3\n"), "image_size"),
        (good.replace("position: [0, 0, 50]", "positon: [0, 0, 50]"), "positon"),
        (good.replace("ground: {material: panel", "ground: {material: pannel"), "ground.material"),
        (format!("{good}boxes:\n  - {{center: [0, 0], size: [1, 1, 1], material: wall, roof: rof}}\n"), "boxes[0].roof"),
        (format!("{good}effects:\n  noise: {{std: 0.01, bitz: 12}}\n"), "bitz"),
        (format!("{good}effects:\n  misregistration: {{bands: [{{band: swir, shift_px: [1, 0]}}]}}\n"), "effects.misregistration.bands[0].band"),
        (format!("{good}effects:\n  sun: {{azimuth_deg: 0, elevation_deg: -5}}\n"), "effects.sun.elevation_deg"),
        (format!("{good}trees:\n  - {{position: [0, 0], trunk_height: 1, crown: [1, 0, 1], crown_material: leaves, trunk_material: bark}}\n"), "trees[0].crown"),
        (good.replace("name: panel\n", "name: panel\nbands: [{name: a, center_nm: 500}]\n"), "bands[0].fwhm_nm"),
        // A NaN centre used to index a spectrum table at usize::MAX and panic.
        (good.replace("name: panel\n", "name: panel\nbands: [{name: a, center_nm: .nan, fwhm_nm: 10}]\n"), "bands[0].center_nm"),
        (good.replace("name: panel\n", "name: panel\nbands: [{name: a, center_nm: 500, fwhm_nm: 1e30}]\n"), "bands[0].fwhm_nm"),
        (good.replace("name: panel\n", "name: panel\nbands: [{name: a, center_nm: 500, fwhm_nm: .inf}]\n"), "bands[0].fwhm_nm"),
        (format!("{good}  - {{orbit: {{center: [0, 0], radius: 5, height: 50, count: 100000000}}}}\n"), "cameras[1].orbit"),
    ];
    for (yaml, key) in cases {
        let e = err(&yaml);
        assert!(e.starts_with("scenes/bad.yaml: "), "{e}");
        assert!(e.contains(key), "`{key}` not named in: {e}");
    }
    // Unknown built-in or file.
    let e = SceneDesc::load("no-such-scene").unwrap_err().to_string();
    assert!(e.contains("no-such-scene") && e.contains("campus"), "{e}");
}

#[test]
fn cli_simulate_writes_a_dataset_and_reports_bad_scenes() {
    let t = TempDir::new("cli");
    let exe = env!("CARGO_BIN_EXE_msnerf");
    let out = t.path().join("ds");
    let o = std::process::Command::new(exe)
        .args([
            "simulate",
            "--scene",
            "ci-small",
            "--width",
            "32",
            "--views",
            "4",
            "--format",
            "u16",
            "--band-files",
            "--seed",
            "5",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ds = msnerf::data::load_dataset(&out, &Default::default()).unwrap();
    assert_eq!((ds.frames.len(), ds.width, ds.height), (4, 32, 24));
    assert!(out.join("README.md").is_file() && out.join("ground_truth.ply").is_file());
    let bad = t.path().join("bad.yaml");
    std::fs::write(&bad, panel_scene(8, 6, "").replace("radius", "x").replace("look_at", "look_at_")).unwrap();
    let o = std::process::Command::new(exe)
        .args(["simulate", "--scene"])
        .arg(&bad)
        .arg("--out")
        .arg(t.path().join("b"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("bad.yaml") && stderr.contains("look_at_"), "{stderr}");
    assert!(!t.path().join("b").exists());
}
