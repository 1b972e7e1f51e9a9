//! The import meets flights as cameras write them:
//!
//! - DLS2 irradiance from the tag layout a real MicaSense Altum (firmware 2.0.0, DLS2 1.2.4) writes, with the
//!   values exifr's test suite reads from such a file: `DLS:` namespace, no `Camera:IrradianceScaleToSIUnits` (so
//!   MicaSense's library assumes 0.01), SolarElevation in radians; checked against the published tags' own
//!   arithmetic (direct sin(el) + scattered), in plain f64 here; and the firmware rule (an old RedEdge-M firmware's
//!   horizontal value is not trusted, it is recomputed from the direct and scattered irradiance with the sun's
//!   elevation at the capture's time and place, which must agree with the camera's own SolarElevation).
//! - A simulated raw flight (the sensor in the simulator): the panel capture found among the flight's and kept out
//!   of it; the Altum's thermal band left out by name without losing a capture; a panel capture in the middle of
//!   the flight named; DLS reflectance within 3 % of the truth on the panel scene's flight.
//! - Bad input: a flight without a GPS fix (tags reading 0 N 0 E, clock 1970) is named, its cameras are not
//!   placed near 0 N 0 E, and `dataset check` refuses the unposed dataset; reflectance 100 times too low (a DLS2
//!   value read without its scale) is named by the import and refused by `dataset check`.

use crate::common::TempDir;
use crate::rig_support::{micasense_xmp, write_rig_tiff, FixtureExif, MsXmp};
use msnerf::rig::calib::interpret;
use msnerf::rig::meta::read_meta;
use msnerf::rig::{import_rig, ImportOptions};
use std::path::{Path, PathBuf};

/// The DLS2 tags of a real Altum Red edge file (exifr's test of `MicaSense_Altum_MSP.tif`).
const ALTUM_HORIZONTAL: f64 = 14.211778962123237;
const ALTUM_DIRECT: f64 = 13.999149989113818;
const ALTUM_SCATTERED: f64 = 7.594971827479635;
const ALTUM_ELEVATION: f64 = 0.4923042795502525;
const ALTUM_AZIMUTH: f64 = 4.721351881011877;

fn altum_xmp() -> String {
    format!(
        r#"<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="Pix4D Camera Information" xmlns:MicaSense="http://micasense.com/MicaSense/1.0/">
<MicaSense:RadiometricCalibration><rdf:Seq><rdf:li>0.0002873074</rdf:li><rdf:li>5.132566e-9</rdf:li><rdf:li>0.00004434347</rdf:li></rdf:Seq></MicaSense:RadiometricCalibration>
<MicaSense:CaptureId>j0QNcuaNsiIJN3yCl26P</MicaSense:CaptureId>
<MicaSense:DarkRowValue><rdf:Seq><rdf:li>3934</rdf:li><rdf:li>3934</rdf:li><rdf:li>3934</rdf:li><rdf:li>3934</rdf:li></rdf:Seq></MicaSense:DarkRowValue>
</rdf:Description>
<rdf:Description rdf:about="Pix4D Camera Information" xmlns:Camera="http://pix4d.com/1.0">
<Camera:RigName>Altum</Camera:RigName><Camera:BandName>Red edge</Camera:BandName>
<Camera:CentralWavelength>717</Camera:CentralWavelength><Camera:WavelengthFWHM>12</Camera:WavelengthFWHM>
<Camera:ModelType>perspective</Camera:ModelType><Camera:PrincipalPoint>3.55453,2.56811</Camera:PrincipalPoint>
<Camera:PerspectiveFocalLength>7.8035429249999995</Camera:PerspectiveFocalLength>
<Camera:PerspectiveFocalLengthUnits>mm</Camera:PerspectiveFocalLengthUnits>
<Camera:Irradiance>17.480027584834886</Camera:Irradiance>
</rdf:Description>
<rdf:Description rdf:about="Pix4D Camera Information" xmlns:DLS="http://micasense.com/DLS/1.0/">
<DLS:SpectralIrradiance>17.480027584834886</DLS:SpectralIrradiance>
<DLS:HorizontalIrradiance>{ALTUM_HORIZONTAL}</DLS:HorizontalIrradiance>
<DLS:DirectIrradiance>{ALTUM_DIRECT}</DLS:DirectIrradiance>
<DLS:ScatteredIrradiance>{ALTUM_SCATTERED}</DLS:ScatteredIrradiance>
<DLS:SolarElevation>{ALTUM_ELEVATION}</DLS:SolarElevation>
<DLS:SolarAzimuth>{ALTUM_AZIMUTH}</DLS:SolarAzimuth>
<DLS:Yaw>-1.2902662267513239</DLS:Yaw><DLS:Pitch>0.03197073237350175</DLS:Pitch><DLS:Roll>0.03794117742142165</DLS:Roll>
</rdf:Description></rdf:RDF></x:xmpmeta>"#
    )
}

fn altum_file(dir: &Path, model: &'static str, software: &'static str) -> PathBuf {
    let p = dir.join(format!("IMG_0001_5-{software}.tif"));
    let exif = FixtureExif {
        exposure: (156121, 100_000_000),
        iso: 800,
        black_level: 4800,
        make: "MicaSense",
        model,
        software,
        // The real file's capture time (UTC) and place.
        datetime: "2020:05:24 16:14:05".into(),
        gps: Some((48.202_437_7, 6.402_746_6, 373.829)),
        focal_plane_res_per_mm: Some(289.855072),
        focal_mm: Some(8.0),
    };
    write_rig_tiff(&p, 64, 48, &vec![6000u16; 64 * 48], &altum_xmp(), &exif);
    p
}

#[test]
fn dls2_irradiance_is_read_as_micasense_reads_a_real_altum_file() {
    let t = TempDir::new("rig-dls2");
    // The published tags agree with themselves: horizontal = direct sin(el) + scattered (tag units).
    let own = ALTUM_DIRECT * ALTUM_ELEVATION.sin() + ALTUM_SCATTERED;
    assert!((own - ALTUM_HORIZONTAL).abs() / ALTUM_HORIZONTAL < 1e-4, "{own}");

    // Altum firmware 2.0.0 (>= 1.2.3): the tag is trusted; no scale tag with a HorizontalIrradiance: 0.01.
    let b = interpret(read_meta(&altum_file(t.path(), "Altum", "v2.0.0")).unwrap()).unwrap();
    assert_eq!(msnerf::rig::dls::irradiance_scale(&b).unwrap().0, 0.01);
    let d = msnerf::rig::dls::dls2(&b).unwrap().expect("a DLS2 file");
    assert!((d.horizontal - 0.01 * ALTUM_HORIZONTAL).abs() < 1e-12, "{d:?}");
    assert!((d.direct - 0.01 * ALTUM_DIRECT).abs() < 1e-12 && (d.scattered - 0.01 * ALTUM_SCATTERED).abs() < 1e-12);
    let (e, source) = msnerf::rig::calibrate::band_dls(&b).unwrap();
    assert_eq!(e, d.horizontal);
    assert!(source.contains("DLS2") && source.contains("0.01"), "{source}");

    // RedEdge-M firmware 5.1.0 (< 5.1.7): the tag is not trusted; direct sin(el) + scattered with the sun's
    // elevation at the capture's time and place, which must agree with the camera's own (its SolarElevation).
    let b = interpret(read_meta(&altum_file(t.path(), "RedEdge-M", "v5.1.0")).unwrap()).unwrap();
    let d = msnerf::rig::dls::dls2(&b).unwrap().expect("a DLS2 file");
    assert!(d.source.contains("5.1.0"), "{}", d.source);
    let want = 0.01 * ALTUM_HORIZONTAL;
    assert!((d.horizontal - want).abs() / want < 2e-3, "recomputed {} against the camera's {want}", d.horizontal);
    // With firmware the rule trusts, and the same wrong-looking tag, the tag wins: the rule decides, not the value.
    assert!(msnerf::rig::dls::horizontal_irradiance_valid(Some("RedEdge-M"), Some("v5.1.7")));
    assert!(!msnerf::rig::dls::horizontal_irradiance_valid(Some("Altum"), Some("v1.2.2")));
    assert!(!msnerf::rig::dls::horizontal_irradiance_valid(Some("RedEdge"), None));
    assert!(msnerf::rig::dls::horizontal_irradiance_valid(Some("RedEdge-P"), None));
}

fn simulate(dir: &Path, sensor: msnerf::sim::sensor::SensorKind, views: usize) -> PathBuf {
    let scene = msnerf::sim::SceneDesc::load("flight-rural").unwrap();
    let o = msnerf::sim::sensor::RawRigOptions { sensor, width: Some(160), views: Some(views), ..Default::default() };
    let out = dir.join(format!("flight-{}", sensor.name()));
    msnerf::sim::sensor::simulate_raw_rig(&scene, &o, &out).unwrap();
    out
}

/// The flight captures the simulation wrote (its truth; a grid rounds `--views` to whole rows and columns).
fn flight_captures(flight: &Path) -> usize {
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(flight.join("truth/flight.json")).unwrap()).unwrap();
    t["captures"].as_array().unwrap().iter().filter(|c| c["kind"] == "flight").count()
}

fn import_options(input: &Path, out: &Path) -> ImportOptions {
    ImportOptions { overwrite: true, threads: 2, ..ImportOptions::new(input, out) }
}

/// Mean of every band over a dataset's images (f32 chunky TIFFs) against the truth dataset's, band by band.
fn mean_ratio(ds: &Path, truth: &Path) -> Vec<f64> {
    let mean = |dir: &Path| -> Vec<f64> {
        let mut sums: Vec<f64> = Vec::new();
        let mut n = 0usize;
        for e in std::fs::read_dir(dir.join("images")).unwrap() {
            let (w, h, bands) = crate::rig_support::read_f32_bands(&e.unwrap().path());
            sums.resize(bands.len(), 0.0);
            for (s, b) in sums.iter_mut().zip(&bands) {
                *s += b.iter().map(|v| *v as f64).sum::<f64>();
            }
            n += w * h;
        }
        sums.iter().map(|s| s / n as f64).collect()
    };
    mean(ds).iter().zip(mean(truth)).map(|(a, b)| a / b).collect()
}

#[test]
fn a_simulated_rededge_flight_imports_with_its_panel_found_and_the_dls_reflectance_of_the_truth() {
    let t = TempDir::new("rig-flight");
    let f = simulate(t.path(), msnerf::sim::sensor::SensorKind::MicasenseRededge, 30);
    let out = t.path().join("ds");
    let s = import_rig(&import_options(&f.join("card"), &out)).unwrap();
    // The panel capture (IMG_0000, taken on the ground) is found and kept out of the flight.
    assert_eq!(s.captures, 30, "{:?}", s.warnings);
    assert!(s.warnings.iter().any(|w| w.contains("IMG_0000") && w.contains("--panel-reflectance")), "{:?}", s.warnings);
    assert_eq!(s.calibration, "dls");
    // DLS2 reflectance: the flight's mean in every band within 3 % of the same flight rendered as reflectance.
    for (b, r) in s.bands.iter().zip(mean_ratio(&out, &f.join("truth/dataset"))) {
        assert!((r - 1.0).abs() < 0.03, "band {b}: imported / truth mean {r}");
    }
    let check = msnerf::data::check_dataset(&out, 1 << 30);
    assert!(check.is_ok(), "{:?}", check.errors);
}

#[test]
fn an_altum_flight_leaves_its_thermal_band_out_by_name_and_keeps_every_capture() {
    let t = TempDir::new("rig-altum");
    let f = simulate(t.path(), msnerf::sim::sensor::SensorKind::MicasenseAltum, 6);
    let s = import_rig(&import_options(&f.join("card"), &t.path().join("ds"))).unwrap();
    assert_eq!(s.captures, flight_captures(&f), "{:?} {:?}", s.skipped, s.warnings);
    assert_eq!(s.bands.len(), 5);
    let want = format!("{} thermal band file(s) (LWIR)", flight_captures(&f));
    assert!(s.warnings.iter().any(|w| w.contains(&want)), "{:?}", s.warnings);
}

#[test]
fn a_panel_capture_in_the_middle_of_the_flight_is_named_and_kept_out_of_it() {
    let t = TempDir::new("rig-panel-mid");
    let f = simulate(t.path(), msnerf::sim::sensor::SensorKind::MicasenseRededge, 8);
    // Swap the panel capture (IMG_0000) with flight capture IMG_0004: the panel now lies between flight captures.
    let dir = f.join("card/0000SET/000");
    for k in 1..=5 {
        let (a, b, tmp) =
            (dir.join(format!("IMG_0000_{k}.tif")), dir.join(format!("IMG_0004_{k}.tif")), dir.join("x.tif"));
        std::fs::rename(&a, &tmp).unwrap();
        std::fs::rename(&b, &a).unwrap();
        std::fs::rename(&tmp, &b).unwrap();
    }
    let s = import_rig(&import_options(&f.join("card"), &t.path().join("ds"))).unwrap();
    assert_eq!(s.captures, flight_captures(&f), "{:?}", s.warnings);
    assert!(
        s.warnings.iter().any(|w| w.contains("IMG_0004") && w.contains("middle of the flight")),
        "{:?}",
        s.warnings
    );
}

/// A small MicaSense-style flight written with the fixture writer: `gps` per capture, DLS2 irradiance `e`.
fn fixture_flight(dir: &Path, gps: Option<(f64, f64, f64)>, datetime: &str, e: f64) {
    std::fs::create_dir_all(dir).unwrap();
    for k in 0..4usize {
        for (suffix, band, center) in [("1", "Blue", 475.0), ("2", "Green", 560.0), ("3", "Red", 668.0)] {
            let px: Vec<u16> = (0..160 * 120)
                .map(|i| {
                    let (x, y) = ((i % 160) as f64, (i / 160) as f64);
                    (6000.0 + 3000.0 * ((x + 9.0 * k as f64) / 7.0).sin() * (y / 5.0).cos()) as u16
                })
                .collect();
            let xmp = micasense_xmp(&MsXmp {
                band,
                center,
                fwhm: 20.0,
                capture: &format!("C{k}"),
                a: [2.5e-4, 0.0, 0.0],
                vignetting_center: [80.0, 60.0],
                vignetting_poly: [0.0; 6],
                focal_px: 140.0,
                principal_mm: [0.8, 0.6],
                distortion: [0.0; 5],
                horizontal_irradiance: Some(e),
                rig: None,
            });
            let exif = FixtureExif {
                exposure: (1, 1000),
                iso: 100,
                black_level: 4800,
                make: "MicaSense",
                model: "RedEdge-M",
                software: "v6.2.1",
                datetime: datetime.to_string(),
                // Cameras without a fix write exactly 0 N 0 E; a real flight moves from capture to capture.
                gps: gps.map(
                    |(la, lo, al)| if la == 0.0 && lo == 0.0 { (la, lo, al) } else { (la, lo + 1e-5 * k as f64, al) },
                ),
                focal_plane_res_per_mm: Some(100.0),
                focal_mm: None,
            };
            write_rig_tiff(&dir.join(format!("IMG_000{k}_{suffix}.tif")), 160, 120, &px, &xmp, &exif);
        }
    }
}

#[test]
fn a_flight_without_a_gps_fix_is_named_and_not_placed_near_zero_north_zero_east() {
    let t = TempDir::new("rig-nofix");
    let input = t.path().join("flight");
    fixture_flight(&input, Some((0.0, 0.0, 0.0)), "1970:01:01 00:00:12", 1.0);
    let out = t.path().join("ds");
    let s = import_rig(&import_options(&input, &out)).unwrap();
    assert!(
        s.warnings.iter().any(|w| w.contains("no capture has a GPS fix") && w.contains("0 N 0 E")),
        "{:?}",
        s.warnings
    );
    assert!(s.warnings.iter().any(|w| w.contains("unset clock")), "{:?}", s.warnings);
    let t_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    assert!(t_json.get("crs").is_none(), "no fix, no UTM zone: {}", t_json["crs"]);
    for f in t_json["frames"].as_array().unwrap() {
        assert!(f["gps"].is_null(), "{}", f["gps"]);
        let m = &f["transform_matrix"];
        let e = m[0][3].as_f64().unwrap();
        assert!(e.abs() < 1.0, "not a UTM easting near 0 N 0 E (166021 in zone 31N): {e}");
    }
    let check = msnerf::data::check_dataset(&out, 1 << 30);
    assert!(check.errors.iter().any(|e| e.contains("not posed") && e.contains("one point")), "{:?}", check.errors);
}

#[test]
fn reflectance_a_hundred_times_too_low_is_named_by_the_import_and_refused_by_dataset_check() {
    let t = TempDir::new("rig-units");
    let input = t.path().join("flight");
    // The light sensor's value 100 times too high (what reading a DLS2 tag without its 0.01 scale does).
    fixture_flight(&input, Some((45.0, 7.0, 400.0)), "2026:06:01 10:00:00", 100.0);
    let out = t.path().join("ds");
    let s = import_rig(&import_options(&input, &out)).unwrap();
    for b in ["Blue", "Green", "Red"] {
        assert!(
            s.warnings.iter().any(|w| w.contains(&format!("band {b}: reflectance implausibly low"))),
            "{b}: {:?}",
            s.warnings
        );
    }
    let check = msnerf::data::check_dataset(&out, 1 << 30);
    assert!(!check.is_ok() && check.errors.iter().any(|e| e.contains("implausibly low")), "{:?}", check.errors);
    // At the right scale the same flight is plausible and checks out.
    fixture_flight(&input, Some((45.0, 7.0, 400.0)), "2026:06:01 10:00:00", 1.0);
    let s = import_rig(&import_options(&input, &out)).unwrap();
    assert!(!s.warnings.iter().any(|w| w.contains("implausibly")), "{:?}", s.warnings);
    assert!(msnerf::data::check_dataset(&out, 1 << 30).is_ok());
}
