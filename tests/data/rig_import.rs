//! `msnerf import rig` on fixtures generated here: tiny 16-bit TIFFs with MicaSense-style and DJI-style XMP
//! and known calibration, written by kamadak-exif's TIFF writer, so expected radiance and reflectance are
//! exact; a simulated flight (3 bands with known sub-pixel band offsets, inverted NIR contrast, a panel capture)
//! imported end to end into a dataset that `train` accepts; and every kind of bad input the issue lists.

use crate::common;
use crate::geo_support;
use crate::rig_support;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use common::TempDir;
use msnerf::rig::calib::{interpret, Vendor};
use msnerf::rig::meta::{read_meta, read_pixels};
use msnerf::rig::radiometry::to_radiance;
use msnerf::rig::{import_rig, ImportOptions, IrradianceSource, Registration, RigError};
use rig_support::{dji_xmp, micasense_xmp, read_f32_bands, write_rig_tiff, DjiXmp, FixtureExif, MsXmp};

const W: u32 = 160;
const H: u32 = 120;
/// File suffix, band name, centre, FWHM, irradiance, base reflectance, contrast, band offset (px) — the suffix
/// order is not the wavelength order.
/// (suffix, name, centre nm, FWHM nm, irradiance, base reflectance, contrast, band offset px).
type BandSpec = (&'static str, &'static str, f64, f64, f64, f64, f64, [f64; 2]);
const BANDS: [BandSpec; 3] = [
    ("1", "NIR", 840.0, 40.0, 0.8, 0.45, -0.4, [-2.3, 1.2]),
    ("2", "Blue", 475.0, 20.0, 1.2, 0.15, 0.2, [0.0, 0.0]),
    ("3", "Red", 668.0, 10.0, 1.0, 0.12, 0.25, [1.6, -0.9]),
];
const A: [f64; 3] = [2.5e-4, 1e-7, 1e-6];
const VC: [f64; 2] = [81.0, 58.5];
const VP: [f64; 6] = [0.0, 2e-5, 0.0, 0.0, 0.0, 0.0];
const TE: f64 = 1e-3;
const BLACK: u16 = 4800;

/// Scene texture in about [0, 1]: 160 Gaussian blobs (sigma 4-9 px, seeded) over a gentle slope. Not periodic,
/// so registration has one answer; smooth, so bilinear resampling errs by well under 1 %.
fn pattern(x: f64, y: f64) -> f64 {
    static BLOBS: std::sync::OnceLock<Vec<[f64; 4]>> = std::sync::OnceLock::new();
    let blobs = BLOBS.get_or_init(|| {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..160).map(|_| [u() * 260.0 - 15.0, u() * 180.0 - 15.0, 4.0 + 5.0 * u(), 0.5 * u() - 0.25]).collect()
    });
    let mut v = 0.5 + 0.001 * (x - 100.0);
    for b in blobs {
        let d2 = (x - b[0]).powi(2) + (y - b[1]).powi(2);
        if d2 < 16.0 * b[2] * b[2] {
            v += b[3] * (-d2 / (2.0 * b[2] * b[2])).exp();
        }
    }
    v.clamp(0.02, 0.98)
}

fn reflectance(band: usize, capture: usize, x: f64, y: f64) -> f64 {
    let (.., base, amp, _) = BANDS[band];
    base + amp * (pattern(x + 7.0 * capture as f64, y + 3.0 * capture as f64) - 0.5)
}

/// The f64 inverse of MicaSense's model: raw DN for radiance `l` at (x, y) (rounded to the u16 it is stored as).
fn raw_for(l: f64, x: f64, y: f64) -> u16 {
    let r = (x - VC[0]).hypot(y - VC[1]);
    let v = 1.0 / (1.0 + VP.iter().enumerate().map(|(i, k)| k * r.powi(i as i32 + 1)).sum::<f64>());
    let row = 1.0 / (1.0 + A[1] * y / TE - A[2] * y);
    let dn = l * TE * 65536.0 / (A[0] * v * row) + BLACK as f64;
    dn.round().clamp(0.0, 65535.0) as u16
}

/// MicaSense's model in f64 (the forward direction).
fn radiance_of(p: u16, x: f64, y: f64) -> f64 {
    let r = (x - VC[0]).hypot(y - VC[1]);
    let v = 1.0 / (1.0 + VP.iter().enumerate().map(|(i, k)| k * r.powi(i as i32 + 1)).sum::<f64>());
    let row = 1.0 / (1.0 + A[1] * y / TE - A[2] * y);
    (v * row * (p as f64 - BLACK as f64)).max(0.0) / TE * A[0] / 65536.0
}

fn exif_for(k: usize) -> FixtureExif {
    FixtureExif {
        exposure: (1, 1000),
        iso: 100,
        black_level: BLACK,
        make: "MicaSense",
        model: "RedEdge-M",
        software: "v6.2.1",
        datetime: format!("2026:06:01 10:00:{:02}", k),
        gps: Some((45.0, 7.0 + 1e-5 * k as f64, 100.0)),
        focal_plane_res_per_mm: Some(100.0),
        focal_mm: None,
    }
}

/// Writes capture `k` (a panel capture when `panel`): one file per band, `IMG_{k:04}_{suffix}.tif`.
fn write_capture(dir: &Path, k: usize, panel: bool, tweak: &dyn Fn(usize, &mut Vec<u16>)) {
    write_capture_shifted(dir, k, panel, tweak, [0.0, 0.0]);
}

/// [`write_capture`] with the Red band moved by `extra` pixels more (a capture whose bands sit differently).
fn write_capture_shifted(dir: &Path, k: usize, panel: bool, tweak: &dyn Fn(usize, &mut Vec<u16>), extra: [f64; 2]) {
    write_capture_with(dir, k, panel, tweak, extra, None);
}

/// Per band (index into [`BANDS`]): `Camera:RigRelatives` (degrees) and `RigTranslations` (metres).
type RigXmp<'a> = Option<&'a dyn Fn(usize) -> ([f64; 3], [f64; 3])>;

/// [`write_capture_shifted`] with the rig's geometry in the XMP when `rig` is given.
fn write_capture_with(
    dir: &Path,
    k: usize,
    panel: bool,
    tweak: &dyn Fn(usize, &mut Vec<u16>),
    extra: [f64; 2],
    rig: RigXmp,
) {
    for (bi, (suffix, name, c, fw, e, ..)) in BANDS.iter().enumerate() {
        let s = if *name == "Red" { [BANDS[bi].7[0] + extra[0], BANDS[bi].7[1] + extra[1]] } else { BANDS[bi].7 };
        let mut px = Vec::with_capacity((W * H) as usize);
        for y in 0..H {
            for x in 0..W {
                // Band image pixel (x, y) shows the scene at (x - s).
                let (sx, sy) = (x as f64 - s[0], y as f64 - s[1]);
                let rho = if panel {
                    let inside = (sx - 80.0).abs() < 24.0 && (sy - 60.0).abs() < 24.0;
                    if inside {
                        0.5
                    } else {
                        0.08 + 0.1 * (pattern(3.0 * sx, 3.0 * sy) - 0.5)
                    }
                } else {
                    reflectance(bi, k, sx, sy)
                };
                px.push(raw_for(rho * e / PI, x as f64, y as f64));
            }
        }
        tweak(bi, &mut px);
        let xmp = micasense_xmp(&MsXmp {
            band: name,
            center: *c,
            fwhm: *fw,
            capture: &format!("CAPTURE{k:04}"),
            a: A,
            vignetting_center: VC,
            vignetting_poly: VP,
            focal_px: 100.0,
            principal_mm: [0.795, 0.595],
            distortion: [0.0; 5],
            horizontal_irradiance: Some(*e),
            rig: rig.map(|r| r(bi)),
        });
        write_rig_tiff(&dir.join(format!("IMG_{k:04}_{suffix}.tif")), W, H, &px, &xmp, &exif_for(k));
    }
}

/// A flight folder: panel capture 0, flight captures 1..=n.
fn flight(dir: &Path, n: usize) -> PathBuf {
    let input = dir.join("flight");
    std::fs::create_dir_all(&input).unwrap();
    write_capture(&input, 0, true, &|_, _| {});
    for k in 1..=n {
        write_capture(&input, k, false, &|_, _| {});
    }
    input
}

fn opts(input: &Path, out: &Path) -> ImportOptions {
    ImportOptions {
        panel_files: vec![input.join("IMG_0000_2.tif")],
        panel_reflectance: vec![0.5],
        threads: 2,
        ..ImportOptions::new(input, out)
    }
}

#[test]
fn micasense_style_fixture_radiance_is_the_published_model() {
    let t = TempDir::new("rig-ms");
    write_capture(t.path(), 1, false, &|_, _| {});
    for (bi, (suffix, name, c, ..)) in BANDS.iter().enumerate() {
        let path = t.path().join(format!("IMG_0001_{suffix}.tif"));
        let b = interpret(read_meta(&path).unwrap()).unwrap();
        assert_eq!((b.vendor, b.band_name.as_str(), b.center_nm), (Vendor::MicaSense, *name, *c));
        assert_eq!(b.capture_key, "CAPTURE0001");
        let l = b.lens.unwrap();
        assert!((l.fx - 100.0).abs() < 1e-9 && (l.cx - 79.5).abs() < 1e-9 && (l.cy - 59.5).abs() < 1e-9, "{l:?}");
        let raw = read_pixels(&b.meta).unwrap();
        let (rad, st) = to_radiance(&b, &raw);
        assert_eq!(st.saturated, 0);
        let mut worst: f64 = 0.0;
        for y in 0..H as usize {
            for x in 0..W as usize {
                let want = radiance_of(raw[y * W as usize + x] as u16, x as f64, y as f64);
                worst = worst.max((rad.at(x, y) as f64 - want).abs() / want);
                // And the radiance of the scene it was made from, to the quantisation of a 16-bit DN.
                let truth = reflectance(bi, 1, x as f64 - BANDS[bi].7[0], y as f64 - BANDS[bi].7[1]) * BANDS[bi].4 / PI;
                assert!((rad.at(x, y) as f64 - truth).abs() / truth < 2e-3, "band {name} ({x},{y})");
            }
        }
        assert!(worst < 1e-5, "band {name}: worst relative error {worst:e}");
    }
}

#[test]
fn dji_style_fixture_uses_microseconds_multiplying_vignetting_and_gain_adjustment() {
    let t = TempDir::new("rig-dji");
    let (cx, cy, vk) = (40.0, 30.0, [1e-3, 2e-5, 0.0, 0.0, 0.0, 0.0]);
    let px: Vec<u16> = (0..80 * 60).map(|i| 4096 + 100 + (i % 997) as u16 * 20).collect();
    let xmp = dji_xmp(&DjiXmp {
        band: "NIR",
        freq: "840(+/-26)nm",
        capture: "UUID-1",
        exposure_us: 2000.0,
        gain: 2.0,
        gain_adjustment: 1.25,
        center: [cx, cy],
        vignetting: vk,
        irradiance: 1.5,
        yaw: 30.0,
    });
    let e = FixtureExif {
        make: "DJI",
        model: "FC6360",
        software: "v6.2.1",
        black_level: 4096,
        gps: None,
        focal_plane_res_per_mm: None,
        ..exif_for(0)
    };
    let path = t.path().join("DJI_0015.TIF");
    write_rig_tiff(&path, 80, 60, &px, &xmp, &e);
    let b = interpret(read_meta(&path).unwrap()).unwrap();
    assert_eq!(b.vendor, Vendor::Dji);
    assert_eq!((b.band_name.as_str(), b.center_nm, b.fwhm_nm), ("NIR", 840.0, Some(52.0)));
    assert_eq!((b.exposure_s, b.gain, b.gain_adjustment, b.irradiance), (2e-3, 2.0, 1.25, Some(1.5)));
    let (rad, _) = to_radiance(&b, &read_pixels(&b.meta).unwrap());
    for y in 0..60 {
        for x in 0..80 {
            let r = (x as f64 - cx).hypot(y as f64 - cy);
            let v = 1.0 + vk[0] * r + vk[1] * r * r; // DJI: the polynomial multiplies
            let want = v * (px[y * 80 + x] as f64 - 4096.0) / (2.0 * 2e-3 * 65536.0) * 1.25;
            assert!((rad.at(x, y) as f64 - want).abs() / want < 1e-5, "({x},{y})");
        }
    }
}

#[test]
fn flight_imports_to_registered_reflectance_that_trains() {
    let t = TempDir::new("rig-flight");
    let input = flight(t.path(), 9);
    let out = t.path().join("dataset");
    let s = import_rig(&opts(&input, &out)).unwrap();
    assert_eq!(s.captures, 9, "{:?}", s.skipped);
    assert!(s.skipped.is_empty() && s.warnings.is_empty(), "{s:?}");
    assert_eq!(s.bands, ["Blue", "Red", "NIR"], "ordered by wavelength, not by suffix");
    // The panel gives back the irradiance the scene was made with, and its own reflectance.
    let p = s.panel.as_ref().unwrap();
    for (bi, want) in [1.2, 1.0, 0.8].iter().enumerate() {
        assert!((p.irradiance[bi] - want).abs() / want < 0.005, "band {bi}: irradiance {}", p.irradiance[bi]);
        assert!((p.captures[0][bi].reflectance_back - 0.5).abs() < 0.005);
    }
    let order = [1usize, 2, 0]; // output band -> BANDS index (Blue, Red, NIR)
                                // The registration found the band offsets (translation part of each homography).
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import_report.json")).unwrap()).unwrap();
    for f in rep["frames"].as_array().unwrap() {
        for (ob, &bi) in order.iter().enumerate() {
            let h = &f["registration"][ob]["warp"]["homography"];
            let m: Vec<f64> = (0..9).map(|i| h[i].as_f64().unwrap()).collect();
            // The band offset is the homography's displacement at the image centre.
            let (x, y) = (80.0, 60.0);
            let d = m[6] * x + m[7] * y + m[8];
            let (dx, dy) = ((m[0] * x + m[1] * y + m[2]) / d - x, (m[3] * x + m[4] * y + m[5]) / d - y);
            let s = BANDS[bi].7;
            assert!((dx - s[0]).abs() < 0.1 && (dy - s[1]).abs() < 0.1, "band {bi}: ({dx:.3}, {dy:.3}) against {s:?}");
        }
    }
    // Every frame: reflectance against the scene's truth in the reference (Blue) camera, after the crop.
    let tj: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let frames = tj["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 9);
    assert_eq!(tj["units"], "reflectance");
    for (k, f) in frames.iter().enumerate() {
        let (w, h, bands) = read_f32_bands(&out.join(f["file_path"].as_str().unwrap()));
        assert_eq!((w as u64, h as u64), (f["w"].as_u64().unwrap(), f["h"].as_u64().unwrap()));
        // Dataset convention: pixel centres at +0.5; the target camera's principal point is 79.5 (integer centres).
        let x0 = 79.5 + 0.5 - f["cx"].as_f64().unwrap();
        let y0 = 59.5 + 0.5 - f["cy"].as_f64().unwrap();
        assert!(w >= 145 && h >= 110, "frame {k} cropped to {w}x{h} from {W}x{H}");
        eprintln!("frame {k}: {w}x{h}, origin ({x0}, {y0})");
        let mut errs = Vec::new();
        for (ob, &bi) in order.iter().enumerate() {
            for y in 2..h - 2 {
                for x in 2..w - 2 {
                    let truth = reflectance(bi, k + 1, x as f64 + x0, y as f64 + y0);
                    errs.push((bands[ob][y * w + x] as f64 - truth).abs() / truth);
                }
            }
        }
        errs.sort_by(f64::total_cmp);
        let (med, p99) = (errs[errs.len() / 2], errs[errs.len() * 99 / 100]);
        assert!(med < 0.005 && p99 < 0.02, "frame {k}: reflectance error median {med:.4}, p99 {p99:.4}");
        assert!(f["gps"]["latitude"].as_f64().is_some() && f["time"].as_str().is_some());
        // The reference band for SfM tools: an 8-bit PNG of the frame's size and stem, stretched to 0-255.
        let stem = f["file_path"].as_str().unwrap().trim_start_matches("images/").trim_end_matches(".tif");
        let png = image::open(out.join("sfm_images").join(format!("{stem}.png"))).unwrap();
        assert_eq!((png.width() as usize, png.height() as usize), (w, h));
        let g = png.as_luma8().expect("8-bit greyscale");
        let (mn, mx) = g.pixels().fold((255u8, 0u8), |(a, b), p| (a.min(p.0[0]), b.max(p.0[0])));
        assert!(mn == 0 && mx == 255, "stretched: {mn}..{mx}");
    }
    // GPS pose priors in the flight's UTM zone (7 E, 45 N: EPSG:32632), where GDAL/PROJ puts the recorded fixes;
    // a nadir camera's image top points to true north (no yaw recorded), which on the grid is turned by the
    // meridian convergence.
    let tj: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(tj["crs"], "EPSG:32632");
    for f in tj["frames"].as_array().unwrap() {
        let (lat, lon, alt) = (
            f["gps"]["latitude"].as_f64().unwrap(),
            f["gps"]["longitude"].as_f64().unwrap(),
            f["gps"]["altitude"].as_f64().unwrap(),
        );
        let want = geo_support::gdaltransform("EPSG:4326", "EPSG:32632", &[[lon, lat, alt], [lon, lat + 1e-4, alt]]);
        let m = &f["transform_matrix"];
        let at = |r: usize, c: usize| m[r][c].as_f64().unwrap();
        for (k, w) in want[0].iter().enumerate() {
            assert!((at(k, 3) - w).abs() < 1e-3, "frame position {k}: {} against GDAL's {w}", at(k, 3));
        }
        let north = [want[1][0] - want[0][0], want[1][1] - want[0][1]];
        let n = (north[0] * north[0] + north[1] * north[1]).sqrt();
        let up_of_image = [at(0, 1), at(1, 1)];
        assert!(
            (up_of_image[0] - north[0] / n).abs() < 1e-6 && (up_of_image[1] - north[1] / n).abs() < 1e-6,
            "image top {up_of_image:?} against true north on the grid {:?}",
            [north[0] / n, north[1] / n]
        );
    }
    // `dataset check` and training accept it.
    let report = msnerf::data::check_dataset(&out, 1 << 30);
    assert!(report.is_ok(), "{report}");
    let text = report.to_string();
    let im = report.import.as_ref().expect("import facts in the check");
    assert_eq!(im.units, "reflectance");
    assert_eq!(im.reference_band.as_deref(), Some("Blue"));
    assert!(im.max_residual_px[1].is_some_and(|v| v < 0.2) && im.max_residual_px[0].is_none(), "{im:?}");
    for want in [
        "units reflectance",
        "Red: radiance in W/(m^2 sr nm), irradiance from panel",
        "registration residual up to",
        "gps priors",
        "crs EPSG:32632 (WGS 84 / UTM zone 32N)",
    ] {
        assert!(text.contains(want), "`dataset check` lacks {want:?}:\n{text}");
    }
    let g = common::gpu();
    let mut model = msnerf::nerf::config::ModelConfig::resolve("tiny").unwrap();
    model.trainer.max_steps = 3;
    let run = t.path().join("run");
    let summary = msnerf::nerf::trainer::train(&g, &common::train_options(&out, &run, model, 256)).unwrap();
    assert_eq!(summary.steps, 3);
}

fn expect_err(r: Result<msnerf::rig::ImportSummary, RigError>) -> String {
    match r {
        Ok(s) => panic!("import succeeded: {s:?}"),
        Err(e) => e.to_string(),
    }
}

fn no_partial_output(parent: &Path, out: &Path) {
    assert!(!out.exists(), "{} exists after a failed import", out.display());
    let leftovers: Vec<_> = std::fs::read_dir(parent)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .collect();
    assert!(leftovers.is_empty(), "staging folders left: {leftovers:?}");
}

#[test]
fn bad_input_is_named_and_nothing_partial_is_left() {
    let t = TempDir::new("rig-bad");
    let input = flight(t.path(), 3);
    let out = t.path().join("out");

    // A capture missing a band: listed and skipped, the run continues.
    std::fs::remove_file(input.join("IMG_0002_3.tif")).unwrap();
    let s = import_rig(&opts(&input, &out)).unwrap();
    assert_eq!(s.captures, 2);
    assert!(
        s.skipped.iter().any(|k| k.what.contains("CAPTURE0002") && k.reason.contains("missing band(s) Red")),
        "{:?}",
        s.skipped
    );
    std::fs::remove_dir_all(&out).unwrap();

    // A file missing a required XMP tag: named with the tag, and its capture skipped.
    let bad = input.join("IMG_0003_1.tif");
    let b = interpret(read_meta(&bad).unwrap()).unwrap();
    let px: Vec<u16> = read_pixels(&b.meta).unwrap().iter().map(|v| *v as u16).collect();
    let xmp = micasense_xmp(&MsXmp {
        band: "NIR",
        center: 840.0,
        fwhm: 40.0,
        capture: "CAPTURE0003",
        a: A,
        vignetting_center: VC,
        vignetting_poly: VP,
        focal_px: 100.0,
        principal_mm: [0.795, 0.595],
        distortion: [0.0; 5],
        horizontal_irradiance: None,
        rig: None,
    })
    .replace("MicaSense:RadiometricCalibration", "MicaSense:Other");
    write_rig_tiff(&bad, W, H, &px, &xmp, &exif_for(3));
    let s = import_rig(&opts(&input, &out)).unwrap();
    assert_eq!(s.captures, 1);
    assert!(
        s.skipped
            .iter()
            .any(|k| k.what.contains("IMG_0003_1.tif") && k.reason.contains("MicaSense:RadiometricCalibration")),
        "{:?}",
        s.skipped
    );
    std::fs::remove_dir_all(&out).unwrap();

    // A band file whose lens model is no camera (a negative focal length): named with its tag, and its capture
    // goes with it even where no other capture shows which band is missing (before, a one-capture flight was
    // written with that band dropped). With no flight capture left the import fails, nothing written.
    let one = t.path().join("one");
    std::fs::create_dir_all(&one).unwrap();
    write_capture(&one, 0, true, &|_, _| {});
    write_capture(&one, 1, false, &|_, _| {});
    let bad = one.join("IMG_0001_3.tif");
    let b = interpret(read_meta(&bad).unwrap()).unwrap();
    let px: Vec<u16> = read_pixels(&b.meta).unwrap().iter().map(|v| *v as u16).collect();
    let xmp = micasense_xmp(&MsXmp {
        band: &b.band_name,
        center: b.center_nm,
        fwhm: 10.0,
        capture: "CAPTURE0001",
        a: A,
        vignetting_center: VC,
        vignetting_poly: VP,
        focal_px: -385.0,
        principal_mm: [0.795, 0.595],
        distortion: [0.0; 5],
        horizontal_irradiance: Some(1.0),
        rig: None,
    });
    write_rig_tiff(&bad, W, H, &px, &xmp, &exif_for(1));
    let mut o = opts(&one, &out);
    o.panel_files = vec![one.join("IMG_0000_2.tif")];
    let e = expect_err(import_rig(&o));
    assert!(e.contains("no complete flight capture"), "{e}");
    assert!(e.contains("IMG_0001_3.tif") && e.contains("Camera:PerspectiveFocalLength"), "{e}");
    assert!(e.contains("CAPTURE0001") && e.contains("its band file") && e.contains("could not be read"), "{e}");
    no_partial_output(t.path(), &out);

    // Saturated panel pixels: counted, excluded, warned.
    let sat_dir = t.path().join("sat");
    std::fs::create_dir_all(&sat_dir).unwrap();
    write_capture(&sat_dir, 0, true, &|_, px| {
        for y in 55..60 {
            for x in 75..85 {
                px[y * W as usize + x] = 65535;
            }
        }
    });
    write_capture(&sat_dir, 1, false, &|_, _| {});
    write_capture(&sat_dir, 2, false, &|_, _| {});
    let mut o = opts(&sat_dir, &out);
    o.panel_files = vec![sat_dir.join("IMG_0000_2.tif")];
    let s = import_rig(&o).unwrap();
    assert_eq!(s.warnings.len(), 3, "{:?}", s.warnings);
    assert!(s.warnings[0].contains("50 saturated panel pixels excluded"), "{:?}", s.warnings);
    let p = s.panel.as_ref().unwrap();
    assert!((p.irradiance[0] - 1.2).abs() / 1.2 < 0.005, "saturated pixels kept out of the mean: {}", p.irradiance[0]);
    std::fs::remove_dir_all(&out).unwrap();

    // A panel that is not there: the file named, with how to give corners; nothing written.
    let mut o = opts(&sat_dir, &out);
    o.panel_files = vec![sat_dir.join("IMG_0001_2.tif")];
    let e = expect_err(import_rig(&o));
    assert!(e.contains("IMG_0001_2.tif") && e.contains("--panel-corners"), "{e}");
    no_partial_output(t.path(), &out);

    // No panel reflectance with a panel: the option named.
    let mut o = opts(&sat_dir, &out);
    o.panel_reflectance.clear();
    assert!(expect_err(import_rig(&o)).contains("--panel-reflectance"));
    no_partial_output(t.path(), &out);

    // Mixed cameras in one folder: both named.
    let mixed = t.path().join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    write_capture(&mixed, 1, false, &|_, _| {});
    let dji = dji_xmp(&DjiXmp {
        band: "Green",
        freq: "560(+/-16)nm",
        capture: "U",
        exposure_us: 1000.0,
        gain: 1.0,
        gain_adjustment: 1.0,
        center: [80.0, 60.0],
        vignetting: [0.0; 6],
        irradiance: 1.0,
        yaw: 0.0,
    });
    write_rig_tiff(
        &mixed.join("DJI_0012.TIF"),
        W,
        H,
        &vec![5000; (W * H) as usize],
        &dji,
        &FixtureExif { make: "DJI", ..exif_for(1) },
    );
    let mut o = opts(&mixed, &out);
    o.panel_files.clear();
    let e = expect_err(import_rig(&o));
    assert!(e.contains("mixed cameras") && e.contains("DJI_0012.TIF") && e.contains("IMG_0001"), "{e}");
    no_partial_output(t.path(), &out);

    // Unknown vendor: what was read and what is missing.
    let plain = t.path().join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    write_rig_tiff(
        &plain.join("a.tif"),
        W,
        H,
        &vec![100; (W * H) as usize],
        "<x/>",
        &FixtureExif { make: "Acme", ..exif_for(1) },
    );
    let mut o = opts(&plain, &out);
    o.panel_files.clear();
    let e = expect_err(import_rig(&o));
    assert!(
        e.contains("a.tif")
            && e.contains("unknown camera vendor")
            && e.contains("Acme")
            && e.contains("Camera:BandName"),
        "{e}"
    );
    no_partial_output(t.path(), &out);

    // The DLS with no irradiance tag (DLS1 files): named, with what to do.
    let dls = t.path().join("dls");
    std::fs::create_dir_all(&dls).unwrap();
    write_capture(&dls, 1, false, &|_, _| {});
    for f in std::fs::read_dir(&dls).unwrap() {
        let p = f.unwrap().path();
        let b = interpret(read_meta(&p).unwrap()).unwrap();
        let px: Vec<u16> = read_pixels(&b.meta).unwrap().iter().map(|v| *v as u16).collect();
        let xmp = micasense_xmp(&MsXmp {
            band: &b.band_name,
            center: b.center_nm,
            fwhm: 10.0,
            capture: "C",
            a: A,
            vignetting_center: VC,
            vignetting_poly: VP,
            focal_px: 100.0,
            principal_mm: [0.795, 0.595],
            distortion: [0.0; 5],
            horizontal_irradiance: None,
            rig: None,
        });
        write_rig_tiff(&p, W, H, &px, &xmp, &exif_for(1));
    }
    let mut o = opts(&dls, &out);
    o.panel_files.clear();
    let e = expect_err(import_rig(&o));
    assert!(e.contains("HorizontalIrradiance") && e.contains("--panel"), "{e}");
    no_partial_output(t.path(), &out);
    // With the irradiance in the files, the DLS path gives the scene's reflectance.
    let o = {
        let mut o = opts(&input, &out);
        o.panel_files.clear();
        o.irradiance = IrradianceSource::Dls;
        o
    };
    let s = import_rig(&o).unwrap();
    assert_eq!(s.calibration, "dls");
}

#[test]
fn shared_rig_warps_are_the_median_over_sampled_captures() {
    let t = TempDir::new("rig-shared");
    let input = flight(t.path(), 6);
    let out = t.path().join("dataset");
    let mut o = opts(&input, &out);
    o.registration = Registration::Rig;
    o.register_sample = 3;
    let s = import_rig(&o).unwrap();
    assert_eq!((s.captures, s.registration), (6, Registration::Rig));
    let spread = s.rig_spread_px.as_ref().unwrap();
    assert!(spread.iter().all(|v| *v < 0.2), "sampled warps disagree: {spread:?}");
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import_report.json")).unwrap()).unwrap();
    assert_eq!(rep["rig_samples"].as_array().unwrap().len(), 3);
    let frames = rep["frames"].as_array().unwrap();
    let order = [1usize, 2, 0];
    for f in frames {
        assert_eq!(f["registration"], frames[0]["registration"], "one warp per band for the whole flight");
    }
    for (ob, &bi) in order.iter().enumerate() {
        let h = &frames[0]["registration"][ob]["warp"]["homography"];
        let m: Vec<f64> = (0..9).map(|i| h[i].as_f64().unwrap()).collect();
        let (x, y) = (80.0, 60.0);
        let d = m[6] * x + m[7] * y + m[8];
        let (dx, dy) = ((m[0] * x + m[1] * y + m[2]) / d - x, (m[3] * x + m[4] * y + m[5]) / d - y);
        let sh = BANDS[bi].7;
        assert!((dx - sh[0]).abs() < 0.1 && (dy - sh[1]).abs() < 0.1, "band {bi}: ({dx:.3}, {dy:.3}) against {sh:?}");
    }
}

#[test]
fn captures_whose_bands_sit_differently_share_one_crop() {
    let t = TempDir::new("rig-crop");
    let input = t.path().join("flight");
    std::fs::create_dir_all(&input).unwrap();
    write_capture(&input, 0, true, &|_, _| {});
    for k in 1..=4 {
        let extra = if k == 2 { [3.0, 2.0] } else { [0.0, 0.0] };
        write_capture_shifted(&input, k, false, &|_, _| {}, extra);
    }
    let out = t.path().join("dataset");
    let mut o = opts(&input, &out);
    o.registration = Registration::Capture;
    let s = import_rig(&o).unwrap();
    assert_eq!(s.captures, 4);
    let tj: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let sizes: Vec<(u64, u64)> =
        tj["frames"].as_array().unwrap().iter().map(|f| (f["w"].as_u64().unwrap(), f["h"].as_u64().unwrap())).collect();
    assert!(sizes.iter().all(|s| *s == sizes[0]), "one image size for the dataset: {sizes:?}");
    // Capture 2's Red band sits 3 px further right: the common crop loses those columns for everyone.
    assert!(sizes[0].0 <= 152 && sizes[0].0 >= 140, "{sizes:?}");
    msnerf::data::load_dataset(&out, &msnerf::data::LoadOptions::default()).unwrap();
}

#[test]
fn raw_geometry_keeps_the_lens_model_with_the_crop_applied() {
    let t = TempDir::new("rig-raw");
    let input = flight(t.path(), 2);
    let (a, b) = (t.path().join("undistorted"), t.path().join("raw"));
    import_rig(&opts(&input, &a)).unwrap();
    let mut o = opts(&input, &b);
    o.undistort = false;
    import_rig(&o).unwrap();
    let read = |d: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("transforms.json")).unwrap()).unwrap()
    };
    let (ta, tb) = (read(&a), read(&b));
    // The fixture's lens has no distortion, so both crops are the same and so must be the principal points.
    let (fa, fb) = (&ta["frames"][0], &tb["frames"][0]);
    assert_eq!(fb["camera_model"], "OPENCV");
    assert_eq!((fa["w"].clone(), fa["h"].clone()), (fb["w"].clone(), fb["h"].clone()));
    for k in ["fl_x", "fl_y", "cx", "cy"] {
        assert!((fa[k].as_f64().unwrap() - fb[k].as_f64().unwrap()).abs() < 1e-9, "{k}: {} against {}", fa[k], fb[k]);
    }
    assert!(fb["k1"].as_f64().is_some());
}

#[test]
fn a_rig_without_a_lens_model_is_refused_by_name_or_uses_exif_focal_length() {
    let t = TempDir::new("rig-nolens");
    let input = flight(t.path(), 2);
    let strip = |focal_mm: Option<f64>| {
        for e in std::fs::read_dir(&input).unwrap() {
            let p = e.unwrap().path();
            let b = interpret(read_meta(&p).unwrap()).unwrap();
            let px: Vec<u16> = read_pixels(&b.meta).unwrap().iter().map(|v| *v as u16).collect();
            let k: usize = p.file_name().unwrap().to_string_lossy()[4..8].parse().unwrap();
            let xmp = micasense_xmp(&MsXmp {
                band: &b.band_name,
                center: b.center_nm,
                fwhm: 10.0,
                capture: &b.capture_key,
                a: A,
                vignetting_center: VC,
                vignetting_poly: VP,
                focal_px: 100.0,
                principal_mm: [0.795, 0.595],
                distortion: [0.0; 5],
                horizontal_irradiance: Some(1.0),
                rig: None,
            })
            .replace("Camera:PerspectiveFocalLength", "Camera:Other");
            write_rig_tiff(&p, W, H, &px, &xmp, &FixtureExif { focal_mm, ..exif_for(k) });
        }
    };
    strip(None);
    let out = t.path().join("out");
    let e = expect_err(import_rig(&opts(&input, &out)));
    assert!(e.contains("Camera:PerspectiveFocalLength") && e.contains("IMG_0001"), "{e}");
    no_partial_output(t.path(), &out);
    // With EXIF FocalLength (8 mm) and FocalPlaneXResolution (100 px/mm): an 800 px pinhole about the centre.
    strip(Some(8.0));
    import_rig(&opts(&input, &out)).unwrap();
    let tj: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let f = &tj["frames"][0];
    assert_eq!((f["fl_x"].as_f64(), f["fl_y"].as_f64()), (Some(800.0), Some(800.0)));
}

/// The rig of [`rig_flight`]: NIR turned and moved beside the reference, Red moved only, Blue the reference.
fn fixture_rig(bi: usize) -> ([f64; 3], [f64; 3]) {
    match BANDS[bi].1 {
        "NIR" => ([0.4, -0.3, 0.2], [0.021, -0.008, 0.001]),
        "Red" => ([0.0, 0.0, 0.0], [-0.015, 0.0, 0.0]),
        _ => ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
    }
}

/// A flight whose files carry `RigRelatives` and `RigTranslations`.
fn rig_flight(dir: &Path, n: usize) -> PathBuf {
    let input = dir.join("flight");
    std::fs::create_dir_all(&input).unwrap();
    write_capture_with(&input, 0, true, &|_, _| {}, [0.0, 0.0], Some(&fixture_rig));
    for k in 1..=n {
        write_capture_with(&input, k, false, &|_, _| {}, [0.0, 0.0], Some(&fixture_rig));
    }
    input
}

/// `import rig --rig-cameras`: no band is warped (each keeps its own camera), `rig_cameras` holds each band's pose
/// composed here from the XMP (MicaSense's `Rx Ry Rz` in degrees, the reference's rotation undone, photogrammetric
/// axes flipped to OpenGL's), masks are written and the dataset trains; without the rig tags it is refused by name.
#[test]
fn rig_cameras_import_keeps_bands_unwarped_and_writes_the_rig() {
    let t = TempDir::new("rig-cameras");
    let input = rig_flight(t.path(), 3);
    let out = t.path().join("dataset");
    let s = import_rig(&ImportOptions { rig_cameras: true, ..opts(&input, &out) }).unwrap();
    assert_eq!((s.captures, s.registration), (3, Registration::None));
    let tf: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let cams = tf["rig_cameras"]["cameras"].as_array().expect("rig_cameras written");
    assert_eq!(cams.len(), 3);
    let rot = |d: [f64; 3]| {
        let (a, b, c) = (d[0].to_radians(), d[1].to_radians(), d[2].to_radians());
        let rx = [[1.0, 0.0, 0.0], [0.0, a.cos(), -a.sin()], [0.0, a.sin(), a.cos()]];
        let ry = [[b.cos(), 0.0, b.sin()], [0.0, 1.0, 0.0], [-b.sin(), 0.0, b.cos()]];
        let rz = [[c.cos(), -c.sin(), 0.0], [c.sin(), c.cos(), 0.0], [0.0, 0.0, 1.0]];
        let mul = |p: [[f64; 3]; 3], q: [[f64; 3]; 3]| {
            let mut m = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] = (0..3).map(|k| p[i][k] * q[k][j]).sum();
                }
            }
            m
        };
        mul(mul(rx, ry), rz)
    };
    let flip = [1.0, -1.0, -1.0];
    for cam in cams {
        let bi = BANDS.iter().position(|b| b.1 == cam["band"].as_str().unwrap()).unwrap();
        let (rel, tr) = fixture_rig(bi);
        let r = rot(rel); // the reference (Blue) has no rotation and no translation
        let m = &cam["rig_from_band"];
        for i in 0..3 {
            for j in 0..3 {
                let want = flip[i] * r[i][j] * flip[j];
                assert!((m[i][j].as_f64().unwrap() - want).abs() < 1e-12, "{} R[{i}][{j}]", BANDS[bi].1);
            }
            assert!((m[i][3].as_f64().unwrap() - flip[i] * tr[i]).abs() < 1e-12, "{} t[{i}]", BANDS[bi].1);
        }
        assert_eq!(cam["fl_x"].as_f64(), Some(100.0));
    }
    // Unwarped: every band shows the scene where its own camera saw it (the fixture's band offsets stay in).
    let ds = msnerf::data::load_dataset(&out, &msnerf::data::LoadOptions::default()).unwrap();
    assert!(ds.rig.is_some() && ds.frames.iter().all(|f| f.mask.is_some()));
    assert_eq!((ds.width, ds.height), (W, H), "no crop");
    let text = msnerf::data::check_dataset(&out, 1 << 30).to_string();
    assert!(text.contains("rig cameras") && text.contains("NIR: 0.0225 world units"), "{text}");
    let img = ds.read_frame(0).unwrap();
    let k = 1; // frame 0 is capture 1 (the panel capture is not a frame)
    let mut worst: f64 = 0.0;
    for (bi, b) in ds.bands.iter().enumerate() {
        let fb = BANDS.iter().position(|x| x.1 == b.name).unwrap();
        for y in 10..H - 10 {
            for x in 10..W - 10 {
                let want = reflectance(fb, k, x as f64 - BANDS[fb].7[0], y as f64 - BANDS[fb].7[1]);
                worst = worst.max((img.get(y, x, bi) as f64 - want).abs());
            }
        }
    }
    assert!(worst < 0.01, "unwarped reflectance off by {worst}");
    // It trains (one-band rays from each band's camera).
    let g = common::gpu();
    let mut model = common::small_tiny_config();
    model.trainer.max_steps = 5;
    let run = t.path().join("run");
    let summary = msnerf::nerf::trainer::train(&g, &common::train_options(&out, &run, model, 64)).unwrap();
    assert!(summary.final_loss.is_finite());

    // A band file without the rig's tags is refused, named; so is --rig-cameras with image registration.
    let plain = flight(&t.path().join("plain"), 1);
    let e = expect_err(import_rig(&ImportOptions { rig_cameras: true, ..opts(&plain, &t.path().join("o1")) }));
    assert!(e.contains("Camera:RigRelatives") && e.contains("IMG_0001_"), "{e}");
    let e = expect_err(import_rig(&ImportOptions {
        rig_cameras: true,
        registration: Registration::Capture,
        ..opts(&input, &t.path().join("o2"))
    }));
    assert!(e.contains("--rig-cameras"), "{e}");
    no_partial_output(t.path(), &t.path().join("o2"));
}
