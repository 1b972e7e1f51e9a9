//! Ground control points, from OpenDroneMap's `gcp_list.txt` to a model fixed on them:
//!
//! - the file as ODM reads it (`opendm/gcp.py`: the CRS on the first line, whitespace-separated fields, `#`
//!   comments, a BOM, points named or grouped by their coordinates), the CRS spellings its headers use (EPSG code,
//!   `WGS84 UTM 32N`, a PROJ UTM string, `EPSG:4326` with x = longitude), and bad files named by line;
//! - the weighted similarity: a weight acts as that many copies of a pair (the definition of the weighted least
//!   squares objective, checked against the unweighted fit on repeated pairs);
//! - the fit with control: GPS with a datum shift and noise, plus exact control points, gives back the true
//!   similarity; one control point pins the translation while the GPS gives the rest; a point left out is checked;
//! - the placing of a point from its pixels: rays of known cameras (with lens distortion) meet at the point, a
//!   mis-click is dropped and named;
//! - a simulated raw flight with `--gcp`: `import rig` carries every click from the raw band files (any band,
//!   through its lens and registration) into the frames' pixels, where the point's projection through the
//!   reference band's true pose lands (the simulator's forward model, independent of the importer's inverse).

use std::path::Path;

use crate::common::TempDir;
use msnerf::geo::gcp::{parse_gcp_list, read_gcp_list};
use msnerf::geo::Crs;
use msnerf::maths::similarity::{fit_similarity, fit_similarity_weighted, Similarity};
use msnerf::poses::model::{PoseCamera, PoseModel, PosedImage};
use msnerf::sfm::control::{place, ControlPoint, GroundControl};
use msnerf::sfm::georef::fit_with_control;

const ODM_FILE: &str = "\u{feff}+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs\n\
# surveyed with RTK, 2026-05-02\n\
307100.125 5341000.5 331.25 1200.5 800.25 IMG_0001_1.tif gcp-a\n\
307100.125\t5341000.5\t331.25\t1100\t790\tIMG_0002_2.tif\tgcp-a\n\
\n\
307150 5341020 330.5 300 200 IMG_0003_1.tif\n\
307150 5341020 330.5 310 600 IMG_0004_1.tif\n";

#[test]
fn odm_gcp_files_parse_as_odm_reads_them() {
    let l = parse_gcp_list(ODM_FILE, Path::new("gcp_list.txt")).unwrap();
    assert_eq!(l.crs.epsg, Some(32632));
    assert_eq!(l.points.len(), 2, "{:?}", l.points);
    assert_eq!(l.points[0].name, "gcp-a");
    assert_eq!(l.points[0].xyz, [307100.125, 5341000.5, 331.25]);
    // The unnamed point is grouped by its coordinates and given a name.
    assert_eq!(l.points[1].name, "gcp2");
    let obs: Vec<(usize, &str, [f64; 2], usize)> =
        l.observations.iter().map(|o| (o.point, o.image.as_str(), o.px, o.line)).collect();
    assert_eq!(
        obs,
        vec![
            (0, "IMG_0001_1.tif", [1200.5, 800.25], 3),
            (0, "IMG_0002_2.tif", [1100.0, 790.0], 4),
            (1, "IMG_0003_1.tif", [300.0, 200.0], 6),
            (1, "IMG_0004_1.tif", [310.0, 600.0], 7),
        ]
    );
    // The other headers ODM accepts.
    for (header, epsg) in [
        ("EPSG:32632", 32632),
        ("WGS84 UTM 32N", 32632),
        ("+proj=utm +zone=33 +south +ellps=WGS84 +units=m", 32733),
        ("EPSG:4326", 4326),
    ] {
        let text = format!("{header}\n6.4 48.19 330 10 20 a.tif p\n6.4 48.19 330 12 20 b.tif p\n");
        let l = parse_gcp_list(&text, Path::new("g.txt")).unwrap_or_else(|e| panic!("{header}: {e}"));
        assert_eq!(l.crs.epsg, Some(epsg), "{header}");
    }
    // Geographic coordinates are longitude, latitude: projected as the GPS is.
    let text = "EPSG:4326\n6.404 48.1927 370.5 10 20 a.tif p\n";
    let l = parse_gcp_list(text, Path::new("g.txt")).unwrap();
    let utm = Crs::parse("EPSG:32632").unwrap();
    let got = l.points_in(&utm).unwrap()[0];
    let want = msnerf::geo::Projector::new(&utm).unwrap().from_geodetic(48.1927, 6.404, 370.5).unwrap();
    assert!((0..3).all(|i| (got[i] - want[i]).abs() < 1e-6), "{got:?} vs {want:?}");
}

#[test]
fn bad_gcp_files_are_named_by_line() {
    let bad = |text: &str| parse_gcp_list(text, Path::new("flight/gcp_list.txt")).unwrap_err().to_string();
    let e = bad("");
    assert!(e.contains("flight/gcp_list.txt") && e.contains("empty"), "{e}");
    let e = bad("NAD27 feet\n1 2 3 4 5 a.tif\n");
    assert!(e.contains("line 1") && e.contains("CRS"), "{e}");
    let e = bad("+proj=utm +zone=32 +datum=NAD27\n1 2 3 4 5 a.tif\n");
    assert!(e.contains("line 1") && e.contains("NAD27"), "{e}");
    let e = bad("EPSG:32632\n# c\n307100 5341000 330 4 5\n");
    assert!(e.contains("line 3") && e.contains("5 fields"), "{e}");
    let e = bad("EPSG:32632\n307100 5341000 nan 4 5 a.tif\n");
    assert!(e.contains("line 2") && e.contains("geo_z"), "{e}");
    let e = bad("EPSG:32632\n1 2 3 4 5 a.tif p\n1 2 4 4 5 b.tif p\n");
    assert!(e.contains("line 3") && e.contains("\"p\""), "{e}");
    let e = bad("EPSG:4326\n48.19 106.4 330 4 5 a.tif p\n");
    assert!(e.contains("line 2") && e.contains("longitude"), "{e}");
    let e = bad("EPSG:32632\n# only a comment\n");
    assert!(e.contains("no observations"), "{e}");
    let e = read_gcp_list(Path::new("/nonexistent/gcp_list.txt")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/gcp_list.txt"), "{e}");
}

fn rot_z(deg: f64) -> [[f64; 3]; 3] {
    let (s, c) = deg.to_radians().sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// A deterministic standard-normal-ish value for (i, k): the sum of 12 uniforms minus 6.
fn noise(i: usize, k: usize) -> f64 {
    use rand::Rng;
    let mut r = crate::common::rng((3 * i + k) as u64);
    (0..12).map(|_| r.random::<f64>()).sum::<f64>() - 6.0
}

#[test]
fn a_weight_acts_as_copies_of_a_pair() {
    let truth = Similarity { scale: 3.0, rotation: rot_z(30.0), translation: [500_000.0, 5_000_000.0, 300.0] };
    let src: Vec<[f64; 3]> = (0..7).map(|i| [i as f64, (i * i % 5) as f64, 0.3 * (i % 3) as f64]).collect();
    let dst: Vec<[f64; 3]> = src
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = truth.apply(*p);
            [q[0] + 0.2 * noise(i, 0), q[1] + 0.2 * noise(i, 1), q[2] + 0.2 * noise(i, 2)]
        })
        .collect();
    let w = [1.0, 3.0, 1.0, 2.0, 1.0, 1.0, 4.0];
    let (mut s2, mut d2) = (Vec::new(), Vec::new());
    for i in 0..7 {
        for _ in 0..w[i] as usize {
            s2.push(src[i]);
            d2.push(dst[i]);
        }
    }
    let a = fit_similarity_weighted(&src, &dst, &w).unwrap();
    let b = fit_similarity(&s2, &d2).unwrap();
    assert!((a.scale - b.scale).abs() < 1e-9, "{} vs {}", a.scale, b.scale);
    for p in &src {
        assert!(dist(a.apply(*p), b.apply(*p)) < 1e-6);
    }
    // Weights must be positive and finite.
    assert!(fit_similarity_weighted(&src, &dst, &[1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0]).is_none());
    assert!(fit_similarity_weighted(&src, &dst, &[1.0, f64::NAN, 1.0, 1.0, 1.0, 1.0, 1.0]).is_none());
}

/// A model frame and the world: cameras over a 100 m x 60 m block, control points on the ground.
fn scene() -> (Similarity, Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let truth = Similarity { scale: 6.0, rotation: rot_z(-50.0), translation: [307_080.0, 5_340_980.0, 330.0] };
    let inv_s = 1.0 / truth.scale;
    let rt = |p: [f64; 3]| -> [f64; 3] {
        let r = truth.rotation;
        std::array::from_fn(|i| (0..3).map(|k| r[k][i] * p[k]).sum::<f64>())
    };
    let to_model = |w: [f64; 3]| {
        let d = [w[0] - truth.translation[0], w[1] - truth.translation[1], w[2] - truth.translation[2]];
        rt(d).map(|c| c * inv_s)
    };
    let cams: Vec<[f64; 3]> = (0..30)
        .map(|i| [307_080.0 + 10.0 * (i % 10) as f64, 5_340_980.0 + 20.0 * (i / 10) as f64, 370.0])
        .map(to_model)
        .collect();
    let gcps = vec![
        [307_085.0, 5_340_985.0, 330.2],
        [307_165.0, 5_340_984.0, 330.0],
        [307_162.0, 5_341_018.0, 330.4],
        [307_088.0, 5_341_020.0, 329.9],
    ];
    (truth, cams, gcps)
}

fn placed(name: &str, world: [f64; 3], model: [f64; 3]) -> msnerf::sfm::control::Placed {
    msnerf::sfm::control::Placed {
        name: name.into(),
        xyz: world,
        model,
        views: 5,
        reprojection_px: 0.3,
        observations: Vec::new(),
    }
}

#[test]
fn control_points_fix_what_the_gps_cannot() {
    let (truth, cams, gcps) = scene();
    let names: Vec<String> = (0..cams.len()).map(|i| format!("f{i}")).collect();
    // GPS: a datum shift of (1.2, -0.8, 1.5) m and 0.5 / 0.8 m of noise per fix.
    let gps: Vec<[f64; 3]> = cams
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let w = truth.apply(*c);
            [w[0] + 1.2 + 0.5 * noise(i, 0), w[1] - 0.8 + 0.5 * noise(i, 1), w[2] + 1.5 + 0.8 * noise(i, 2)]
        })
        .collect();
    let inverse_model = |w: [f64; 3]| {
        let d = [w[0] - truth.translation[0], w[1] - truth.translation[1], w[2] - truth.translation[2]];
        let r = truth.rotation;
        std::array::from_fn::<f64, 3, _>(|i| (0..3).map(|k| r[k][i] * d[k]).sum::<f64>() / truth.scale)
    };
    let control: Vec<_> =
        gcps.iter().enumerate().map(|(i, g)| placed(&format!("g{i}"), *g, inverse_model(*g))).collect();
    let gps_only = fit_with_control(&names, &cams, &gps, 1.0, &[], vec![]).unwrap();
    let with = fit_with_control(&names, &cams, &gps, 1.0, &control, vec![]).unwrap();
    // Judged at the corners of the block on the ground: where a tilt shows most.
    let probe = [[307_080.0, 5_340_980.0, 330.0], [307_180.0, 5_341_020.0, 330.0]].map(inverse_model);
    let err = |s: &Similarity| probe.iter().map(|p| dist(s.apply(*p), truth.apply(*p))).fold(0.0, f64::max);
    assert!(err(&gps_only.similarity) > 0.5, "GPS alone keeps the datum shift: {}", err(&gps_only.similarity));
    assert!(err(&with.similarity) < 0.01, "with control: {}", err(&with.similarity));
    let c = with.control.as_ref().unwrap();
    assert_eq!(c.points.len(), 4);
    assert!(c.rms_m < 0.005 && c.check_rms_m.unwrap() < 0.02, "{c:?}");
    // The GPS residuals are reported under the final fit: the datum shift shows in them.
    assert!(with.rms_m > 1.5, "{}", with.rms_m);

    // One control point pins the translation; the GPS still gives rotation and scale.
    let one = fit_with_control(&names, &cams, &gps, 1.0, &control[..1], vec![]).unwrap();
    assert!(dist(one.similarity.apply(control[0].model), gcps[0]) < 0.01);
    assert!(
        err(&one.similarity) < err(&gps_only.similarity),
        "{} vs {}",
        err(&one.similarity),
        err(&gps_only.similarity)
    );

    // Without GPS, three points fix the fit and two do not.
    assert!(fit_with_control(&[], &[], &[], 1.0, &control[..3], vec![]).is_ok());
    let e = fit_with_control(&[], &[], &[], 1.0, &control[..2], vec!["point g2: not registered".into()]).unwrap_err();
    assert!(e.contains("2 control point(s)") && e.contains("not registered"), "{e}");

    // A point surveyed 0.5 m too high: the fit with it hides part of the error in its residual, the fit without it
    // (its check) shows all of it.
    let mut off = control.clone();
    off[2].xyz[2] += 0.5;
    let f = fit_with_control(&names, &cams, &gps, 1.0, &off, vec![]).unwrap();
    let p = &f.control.as_ref().unwrap().points[2];
    let check = p.check_m.unwrap();
    assert!((check[2] + 0.5).abs() < 0.02 && check[0].abs() < 0.02 && check[1].abs() < 0.02, "{p:?}");
    assert!(p.residual_m[2].abs() < 0.45, "{p:?}");
    // The GPS's datum shift comes back from the fixes once the points hold the frame.
    let g = with.control.as_ref().unwrap().gps_shift_m.unwrap();
    assert!(dist(g, [1.2, -0.8, 1.5]) < 0.5, "{g:?}");
}

/// A nadir camera at `c` (OpenGL axes: looking down -z), yawed, with OPENCV distortion.
fn camera(id: u64, c: [f64; 3], yaw_deg: f64) -> PosedImage {
    let r = rot_z(yaw_deg);
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[i][j];
        }
        m[i][3] = c[i];
    }
    m[3][3] = 1.0;
    PosedImage {
        id,
        name: format!("IMG_{id:04}.png"),
        c2w: m,
        camera: PoseCamera {
            width: 1280,
            height: 960,
            model: "OPENCV",
            keys: vec![
                ("fl_x", 1450.0),
                ("fl_y", 1452.0),
                ("cx", 640.5),
                ("cy", 480.5),
                ("k1", -0.09),
                ("k2", 0.12),
                ("p1", 0.0004),
                ("p2", -0.0003),
            ],
        },
    }
}

#[test]
fn a_point_is_placed_from_its_pixels_and_a_misclick_is_dropped() {
    let images: Vec<PosedImage> =
        (0..5).map(|i| camera(i + 1, [10.0 * i as f64 - 20.0, 3.0 * (i % 2) as f64, 40.0], 7.0 * i as f64)).collect();
    let model = PoseModel { tool: "test", images: images.clone(), ..Default::default() };
    let truth = [1.5, 2.0, 0.3];
    // Distortion round trip: the ray of a point's projection passes through the point.
    for im in &images {
        let px = msnerf::sfm::control::project(im, truth).unwrap();
        let (o, d) = msnerf::sfm::control::pixel_ray(im, px);
        let v = [truth[0] - o[0], truth[1] - o[1], truth[2] - o[2]];
        let t = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
        let miss = dist([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]], truth);
        assert!(miss < 1e-6, "{} misses by {miss} m", im.name);
    }
    let mut obs: Vec<(String, [f64; 2])> = images
        .iter()
        .map(|im| (format!("images/IMG_{:04}.tif", im.id), msnerf::sfm::control::project(im, truth).unwrap()))
        .collect();
    obs[3].1[0] += 30.0; // a mis-click
    obs.push(("images/IMG_0099.tif".into(), [10.0, 10.0])); // a frame the model did not register
    let gc = GroundControl {
        crs: "EPSG:32632".into(),
        points: vec![ControlPoint { name: "p1".into(), xyz: [0.0; 3], observations: obs }],
    };
    let (placed, notes) = place(&model, &gc);
    assert_eq!(placed.len(), 1, "{notes:?}");
    assert!(dist(placed[0].model, truth) < 1e-6, "{:?}", placed[0]);
    assert_eq!(placed[0].views, 4);
    assert!(notes.iter().any(|n| n.contains("IMG_0004") && n.contains("dropped")), "{notes:?}");
    assert!(notes.iter().any(|n| n.contains("IMG_0099") && n.contains("not registered")), "{notes:?}");
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

#[test]
fn import_carries_clicks_in_raw_band_files_into_the_frames_pixels() {
    let t = TempDir::new("gcp-import");
    let scene = msnerf::sim::SceneDesc::load("flight-rural").unwrap();
    let o = msnerf::sim::sensor::RawRigOptions { width: Some(160), gcp: 4, threads: 2, ..Default::default() };
    let flight = t.path().join("flight");
    msnerf::sim::sensor::simulate_raw_rig(&scene, &o, &flight).unwrap();
    // The clicks replaced by the exact projections, so that the comparison below can be tight.
    let truth_gcp = read_json(&flight.join("truth/gcp.json"));
    let mut list = read_gcp_list(&flight.join("gcp_list.txt")).unwrap();
    let exact = truth_gcp["observations"].as_array().unwrap();
    assert_eq!(exact.len(), list.observations.len());
    let bands_used: std::collections::BTreeSet<String> =
        list.observations.iter().map(|o| o.image.rsplit('_').next().unwrap().to_string()).collect();
    assert!(bands_used.len() >= 4, "clicks in several bands: {bands_used:?}");
    for (ob, e) in list.observations.iter_mut().zip(exact) {
        ob.px = [e["px"][0].as_f64().unwrap(), e["px"][1].as_f64().unwrap()];
    }
    let exact_file = t.path().join("gcp_exact.txt");
    std::fs::write(&exact_file, list.to_text(&list.crs.key())).unwrap();

    let out = t.path().join("dataset");
    let opts = msnerf::rig::ImportOptions {
        ground_control: msnerf::rig::ground_control::GcpSource::File(exact_file.clone()),
        threads: 2,
        ..msnerf::rig::ImportOptions::new(flight.join("card"), &out)
    };
    let s = msnerf::rig::import_rig(&opts).unwrap();
    let tj = read_json(&out.join("transforms.json"));
    let gc = &tj["ground_control"];
    assert_eq!(gc["crs"], "EPSG:32632");
    let points = gc["points"].as_array().unwrap();
    assert_eq!(points.len(), 4, "{:?}", s.warnings);

    // Where each point's true position lands in each frame: the reference band's true pose and the frame's pinhole.
    let ft = read_json(&flight.join("truth/flight.json"));
    let profile = msnerf::sim::sensor::SensorProfile::new(msnerf::sim::sensor::SensorKind::MicasenseRededge)
        .scaled(ft["width"].as_u64().unwrap() as u32, ft["height"].as_u64().unwrap() as u32);
    let reference = tj["reference_band"].as_str().unwrap();
    let band = profile.bands.iter().find(|b| b.name == reference).unwrap();
    let rig = msnerf::sim::sensor::forward::RigPose::of(&profile, band);
    let mut worst: f64 = 0.0;
    let mut n = 0;
    for p in points {
        let xyz: [f64; 3] = serde_json::from_value(p["xyz"].clone()).unwrap();
        for ob in p["observations"].as_array().unwrap() {
            let file = ob["file_path"].as_str().unwrap();
            let frame = tj["frames"].as_array().unwrap().iter().find(|f| f["file_path"] == file).unwrap();
            let cap =
                ft["captures"].as_array().unwrap().iter().find(|c| c["capture_id"] == frame["capture_id"]).unwrap();
            let c2w: [[f64; 4]; 4] = serde_json::from_value(cap["reference_c2w"].clone()).unwrap();
            let pinhole = msnerf::rig::calib::Lens {
                fx: frame["fl_x"].as_f64().unwrap(),
                fy: frame["fl_y"].as_f64().unwrap(),
                cx: frame["cx"].as_f64().unwrap() - 0.5,
                cy: frame["cy"].as_f64().unwrap() - 0.5,
                k1: 0.0,
                k2: 0.0,
                k3: 0.0,
                p1: 0.0,
                p2: 0.0,
            };
            let (u, v) = msnerf::sim::sensor::forward::project(&pinhole, &rig, &c2w, xyz).unwrap();
            let got = [ob["px"][0].as_f64().unwrap(), ob["px"][1].as_f64().unwrap()];
            worst = worst.max((got[0] - (u + 0.5)).hypot(got[1] - (v + 0.5)));
            n += 1;
        }
    }
    assert!(n >= 8, "{n} observations");
    // The band registration's own error (a few hundredths of a pixel) and the rig's offsets are all that is left.
    assert!(worst < 0.2, "worst observation {worst:.3} px from the true projection");

    // An observation in an image the flight does not have is named; a point left with one view is named and left
    // out; a file without any usable point stops the import before anything is written.
    let mut text = std::fs::read_to_string(&exact_file).unwrap();
    text.push_str("307100 5341000 330 10 10 IMG_9999_1.tif lonely\n");
    let edited = t.path().join("gcp_edited.txt");
    std::fs::write(&edited, &text).unwrap();
    let s = msnerf::rig::import_rig(&msnerf::rig::ImportOptions {
        ground_control: msnerf::rig::ground_control::GcpSource::File(edited),
        overwrite: true,
        ..opts.clone()
    })
    .unwrap();
    assert!(s.warnings.iter().any(|w| w.contains("IMG_9999_1.tif")), "{:?}", s.warnings);
    assert!(s.warnings.iter().any(|w| w.contains("lonely") && w.contains("not used")), "{:?}", s.warnings);
    let useless = t.path().join("gcp_useless.txt");
    std::fs::write(&useless, "EPSG:32632\n307100 5341000 330 10 10 IMG_9999_1.tif p\n").unwrap();
    let out2 = t.path().join("dataset2");
    let e = msnerf::rig::import_rig(&msnerf::rig::ImportOptions {
        ground_control: msnerf::rig::ground_control::GcpSource::File(useless.clone()),
        ..msnerf::rig::ImportOptions::new(flight.join("card"), &out2)
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("gcp_useless.txt") && e.contains("two usable observations"), "{e}");
    assert!(!out2.exists(), "nothing written");
    // A broken file stops the import at once, naming the line.
    std::fs::write(&useless, "EPSG:32632\n307100 5341000 330 10\n").unwrap();
    let e = msnerf::rig::import_rig(&msnerf::rig::ImportOptions {
        ground_control: msnerf::rig::ground_control::GcpSource::File(useless),
        ..msnerf::rig::ImportOptions::new(flight.join("card"), &out2)
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("line 2") && e.contains("4 fields"), "{e}");
}

/// COLMAP from apt, or a failure that says how to get it.
fn require_colmap() {
    let ok = std::process::Command::new("sh").args(["-c", "command -v colmap"]).output().map(|o| o.status.success());
    assert!(
        ok.unwrap_or(false),
        "COLMAP not found: install it with `apt-get install colmap` (tools/setup-debian.sh does)"
    );
}

#[test]
fn sfm_fixes_a_raw_flight_on_its_control_points_and_finds_the_gps_datum_shift() {
    require_colmap();
    let t = TempDir::new("gcp-sfm");
    let scene = msnerf::sim::SceneDesc::load("flight-rural").unwrap();
    let o = msnerf::sim::sensor::RawRigOptions { width: Some(240), gcp: 5, threads: 2, ..Default::default() };
    let flight = t.path().join("flight");
    msnerf::sim::sensor::simulate_raw_rig(&scene, &o, &flight).unwrap();
    let data = t.path().join("dataset");
    let opts = msnerf::rig::ImportOptions {
        ground_control: msnerf::rig::ground_control::GcpSource::File(flight.join("gcp_list.txt")),
        threads: 2,
        ..msnerf::rig::ImportOptions::new(flight.join("card"), &data)
    };
    msnerf::rig::import_rig(&opts).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
        .args(["sfm", data.to_str().unwrap(), "--band", "pan"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("ground control: 5 point(s)") && text.contains("check rms"), "{text}");
    let rep = read_json(&data.join("colmap/sfm_report.json"));
    let c = &rep["georef"]["control"];
    assert_eq!(c["points"].as_array().unwrap().len(), 5, "{c}");
    for p in c["points"].as_array().unwrap() {
        assert!(p["views"].as_u64().unwrap() >= 4 && p["reprojection_px"].as_f64().unwrap() < 2.0, "{p}");
    }
    assert!(c["rms_m"].as_f64().unwrap() < 0.25 && c["check_rms_m"].as_f64().unwrap() < 0.5, "{c}");
    // The datum shift the simulation put into every fix comes back from the fixes once the points hold the frame.
    let ft = read_json(&flight.join("truth/flight.json"));
    let truth_shift: [f64; 3] = serde_json::from_value(ft["gps"]["datum_shift_m"].clone()).unwrap();
    let found: [f64; 3] = serde_json::from_value(c["gps_shift_m"].clone()).unwrap();
    assert!(dist(found, truth_shift) < 0.5, "found {found:?}, simulated {truth_shift:?}");
    // The cameras as delivered, nothing removed: where the reference band's camera truly was.
    let tj = read_json(&data.join("transforms.json"));
    let profile = msnerf::sim::sensor::SensorProfile::new(msnerf::sim::sensor::SensorKind::MicasenseRededge)
        .scaled(ft["width"].as_u64().unwrap() as u32, ft["height"].as_u64().unwrap() as u32);
    let band = profile.bands.iter().find(|b| b.name == tj["reference_band"].as_str().unwrap()).unwrap();
    let rig = msnerf::sim::sensor::forward::RigPose::of(&profile, band);
    let mut err: Vec<f64> = Vec::new();
    for f in tj["frames"].as_array().unwrap() {
        let cap = ft["captures"].as_array().unwrap().iter().find(|c| c["capture_id"] == f["capture_id"]).unwrap();
        let m: [[f64; 4]; 4] = serde_json::from_value(cap["reference_c2w"].clone()).unwrap();
        let off = [rig.center.x, -rig.center.y, -rig.center.z];
        let truth: [f64; 3] = std::array::from_fn(|i| m[i][3] + (0..3).map(|k| m[i][k] * off[k]).sum::<f64>());
        let got: [f64; 3] = std::array::from_fn(|i| f["transform_matrix"][i][3].as_f64().unwrap());
        err.push(dist(got, truth));
    }
    err.sort_by(f64::total_cmp);
    let median = err[err.len() / 2];
    assert!(median < 0.3, "camera centres a median {median:.3} m from the truth (datum shift {truth_shift:?})");
}
