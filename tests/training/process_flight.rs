//! `msnerf process` end to end at CI size: a raw flight written by the sensor in the simulator (MicaSense
//! RedEdge-MX files of the `flight-rural` scene, 30 captures of 240x180 and a panel capture, GPS with noise and a
//! datum shift, five ground control points) becomes a dataset, COLMAP poses, a trained run, a LAS cloud, a DSM, a true ortho, an NDVI raster and
//! an HTML report in one call; then the stage records do their job:
//!
//! - every stage ran; the products carry the flight's UTM CRS (read back by GDAL and from the LAS bytes);
//! - the panel capture was found and kept out of the flight, and the panel reflectance comes back;
//! - the held-out views are far above a collapsed field (every band's PSNR above 25 dB);
//! - the report parses: every section is present, every number in it is finite, every embedded PNG decodes;
//! - a training interrupted as it starts fails its stage and writes no record; the rerun skips what is done and
//!   resumes the training from its checkpoint;
//! - a rerun skips every stage and rewrites nothing; an output edited by hand stops the run naming the file;
//!   `--redo survey` makes the survey and the report again and nothing before them;
//! - `--poses` takes another tool's model (the COLMAP model of the first project) instead of running COLMAP;
//! - the flight's five ground control points (`gcp_list.txt`) fix the georeferencing: every point placed, its check
//!   residual small, the report's ground-control section present, the products judged as delivered.
//!
//! The acceptance figures (registration, reflectance, cloud and DSM against the truth) are the benchmark's
//! (`make flight-acceptance`, docs/results); this test proves the chain and its bookkeeping.

use std::path::{Path, PathBuf};

use super::common::{gpu, TempDir};
use super::geo_support::{gdalinfo_json, las_wkt};
use msnerf::process::{process, ProcessOptions, Stage};

fn simulate(dir: &Path) -> PathBuf {
    let scene = msnerf::sim::SceneDesc::load("flight-rural").expect("built-in scene");
    // Five ground control points in the flight folder's gcp_list.txt (OpenDroneMap's layout).
    let o = msnerf::sim::sensor::RawRigOptions { width: Some(240), gcp: 5, ..Default::default() };
    msnerf::sim::sensor::simulate_raw_rig(&scene, &o, &dir.join("flight")).expect("raw flight");
    dir.join("flight")
}

/// The panel's reflectance per band in wavelength order, from the simulation's calibration sheet.
fn panel_sheet(flight_root: &Path) -> Vec<f64> {
    let p: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(flight_root.join("truth/panel.json")).unwrap()).unwrap();
    let mut bands: Vec<(f64, f64)> = p["bands"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| (b["center_nm"].as_f64().unwrap(), b["reflectance"].as_f64().unwrap()))
        .collect();
    bands.sort_by(|a, b| a.0.total_cmp(&b.0));
    bands.into_iter().map(|b| b.1).collect()
}

fn options(flight: &Path, project: &Path, panel: Vec<f64>) -> ProcessOptions {
    let mut device = msnerf::gpu::ContextDesc::from_env();
    if device.validation == msnerf::gpu::Validation::Off {
        device.validation = msnerf::gpu::Validation::IfAvailable;
    }
    ProcessOptions {
        flight: flight.join("card"),
        project: project.to_path_buf(),
        panel_reflectance: panel,
        irradiance: msnerf::rig::IrradianceSource::Auto,
        units: msnerf::rig::Units::Reflectance,
        reference_band: None,
        crs: None,
        ground_control: msnerf::rig::ground_control::GcpSource::File(flight.join("gcp_list.txt")),
        poses: None,
        model: "demo".into(),
        hardware: "auto".into(),
        time_budget_s: Some(45.0),
        max_steps: None,
        seed: Some(7),
        images_only: false,
        gsd: None,
        cloud_rays: 40_000,
        indices: vec![msnerf::output::raster::indices::VegetationIndex::Ndvi],
        fill: msnerf::nerf::survey::DsmFill::default(),
        stop_after: None,
        redo: None,
        threads: 2,
        device,
        stop: None,
    }
}

/// A stage's record.
fn rec_of(project: &Path, st: Stage) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(project.join(format!("stages/{}.json", st.name()))).unwrap()).unwrap()
}

fn statuses(s: &msnerf::process::ProcessSummary) -> Vec<(Stage, String)> {
    s.stages.iter().map(|o| (o.stage, o.status.clone())).collect()
}

/// Every `data:image/png;base64,...` of the report, decoded with the `png` crate; the sections' ids; and every
/// number in the report's text (outside the images).
fn parse_report(html: &str) -> (Vec<(u32, u32)>, Vec<String>, Vec<String>) {
    use base64::Engine as _;
    let mut images = Vec::new();
    let mut text = String::new();
    let mut rest = html;
    while let Some(i) = rest.find("data:image/png;base64,") {
        text.push_str(&rest[..i]);
        let tail = &rest[i + "data:image/png;base64,".len()..];
        let end = tail.find('"').expect("a closed src attribute");
        let bytes = base64::engine::general_purpose::STANDARD.decode(&tail[..end]).expect("valid base64");
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let reader = dec.read_info().expect("an embedded PNG decodes");
        images.push((reader.info().width, reader.info().height));
        rest = &tail[end..];
    }
    text.push_str(rest);
    let sections: Vec<String> =
        text.split("<section id=\"").skip(1).map(|s| s.split('"').next().unwrap().to_string()).collect();
    // Words of the visible text that look numeric (digits, a sign, a point) or that a bad number prints as.
    let plain: String = text.split('<').map(|s| s.split_once('>').map_or(s, |(_, t)| t)).collect::<Vec<_>>().join(" ");
    let words: Vec<String> = plain
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';' || c == '(' || c == ')' || c == ':')
        .filter(|w| !w.is_empty())
        .map(str::to_string)
        .collect();
    (images, sections, words)
}

#[test]
fn a_raw_flight_becomes_survey_products_and_a_report_in_one_call_and_reruns_skip_what_is_current() {
    let _g = gpu();
    let t = TempDir::new("process-flight");
    let flight = simulate(t.path());
    let project = t.path().join("project");
    let o = options(&flight, &project, panel_sheet(&flight));

    // Interrupted as training starts (Ctrl-C): the stage fails, its checkpoint stays, and no record is written.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let interrupted = ProcessOptions { stop: Some(stop.clone()), ..o.clone() };
    let e = process(&interrupted, &mut |l| {
        if l.contains("] train: training") {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("train") && e.contains("interrupted"), "{e}");
    assert!(!project.join("stages/train.json").exists());

    // The rerun skips what is done, resumes the training from its checkpoint and finishes.
    let mut lines = Vec::new();
    let s = process(&o, &mut |l| lines.push(l.to_string())).unwrap_or_else(|e| panic!("{e}\n{}", lines.join("\n")));
    let st = statuses(&s);
    for (stage, status) in &st {
        let want = if *stage >= Stage::Train { "ran" } else { "current" };
        assert_eq!(status, want, "{stage:?}: {st:?}");
    }
    assert!(lines.iter().any(|l| l.contains("resuming from the run's checkpoint")), "{}", lines.join("\n"));

    // The import found the panel capture, calibrated from it, and kept it out of the flight.
    let rec = |st: Stage| rec_of(&project, st);
    let import = &rec(Stage::Import)["summary"];
    assert_eq!(import["captures"], 30, "{import}");
    assert_eq!(import["calibration"], "panel");
    let back = &import["panel"]["captures"][0];
    for (b, want) in back.as_array().unwrap().iter().zip(panel_sheet(&flight)) {
        let got = b["reflectance_back"].as_f64().unwrap();
        assert!((got - want).abs() < 1e-9, "{b}");
    }
    // COLMAP registered the flight and geo-registered it on the control points, the GPS giving the rest.
    let poses = &rec(Stage::Poses)["summary"];
    assert!(poses["registered"].as_u64().unwrap() >= 29, "{poses}");
    assert!(poses["georef"]["rms_m"].as_f64().unwrap() < 3.0, "{poses}");
    let control = &poses["georef"]["control"];
    assert_eq!(control["points"].as_array().map(|p| p.len()), Some(5), "{poses}");
    assert!(control["check_rms_m"].as_f64().unwrap() < 0.5, "{control}");
    // The bundle adjustment on the control points ran and did not make the images disagree.
    let adj = &control["adjustment"];
    assert!(adj["iterations"].as_u64().unwrap() >= 1, "{control}");
    assert!(adj["rms_px_after"].as_f64().unwrap() <= adj["rms_px_before"].as_f64().unwrap() + 0.05, "{control}");

    // One host budget for the flight: the exports hold decoded training images within the training cache's budget.
    let budget = rec(Stage::Train)["summary"]["host_budget_bytes"].as_u64().expect("the train stage's host budget");
    for st in [Stage::Cloud, Stage::Survey] {
        assert_eq!(rec(st)["summary"]["image_budget_bytes"].as_u64(), Some(budget), "{st:?}");
    }

    // Held-out views: a field that collapsed (transparent, or stuck at a constant) scores below 30 dB here.
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(project.join("run/eval.json")).unwrap()).unwrap();
    for b in eval["bands"].as_array().unwrap() {
        assert!(b["psnr"].as_f64().unwrap() > 25.0, "{b}");
    }

    // Products in the flight's UTM zone (32N), read back by GDAL and from the LAS bytes.
    let products = project.join("products");
    for raster in ["dsm.tif", "ortho.tif", "ortho_ndvi.tif", "dtm.tif", "chm.tif"] {
        let info = gdalinfo_json(&products.join(raster));
        let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap_or_default();
        assert!(wkt.contains("UTM zone 32N"), "{raster}: {wkt}");
    }
    let (wkt, bit) = las_wkt(&products.join("cloud.las"));
    assert!(bit && wkt.unwrap_or_default().contains("UTM zone 32N"), "cloud.las CRS");
    let survey = &rec(Stage::Survey)["summary"]["stats"];
    let (valid, cells) = (survey["valid"].as_f64().unwrap(), survey["cells"].as_f64().unwrap());
    // 45 s of training on a CPU leaves a young field whose weights still spread over most cells (the spread filter
    // makes them nodata: 60-75 % here); a field that learnt the ground gives a good part of them a height. Coverage
    // itself is the benchmark's (and issue 51's) to measure.
    assert!(valid > 0.1 * cells, "DSM cells with a height: {valid} of {cells}: {survey}");

    // `bench flight` on the same project (no direct flight): every figure present and plausible for a young field.
    // The acceptance's own thresholds are the benchmark's to report (docs/results/flight.md); here the
    // measurement itself is checked: the truth it reads, and figures any working chain stays within.
    let acc = msnerf::bench::flight::flight_acceptance(&flight, &project, None).expect("bench flight");
    assert_eq!((acc.captures, acc.crs.as_str()), (30, "EPSG:32632"));
    assert!(acc.registered >= 29, "{}", acc.registered);
    assert_eq!(acc.reflectance.len(), 5);
    for r in &acc.reflectance {
        assert!(r.pixels > 1000 && (r.median_ratio - 1.0).abs() < 0.03, "{r:?}");
    }
    for f in &acc.image_fidelity {
        assert!(f.pixels > 10_000 && f.psnr_db > 30.0 && f.psnr_db.is_finite(), "{f:?}");
    }
    assert!(acc.registration.failures(0.1, 0.3).is_empty(), "{:?}", acc.registration.failures(0.1, 0.3));
    let tilt = acc.georeferencing["tilt_deg"].as_f64().unwrap();
    let icp_tilt = acc.relative_transform["tilt_deg"].as_f64().unwrap();
    // The GPS fit's tilt is the noise's; the cloud's rigid fit to the surface finds about the same one.
    assert!(tilt < 2.0 && (icp_tilt - tilt).abs() < 0.5, "{tilt} vs {icp_tilt}: {}", acc.relative_transform);
    let (abs_m, rel_m) =
        (acc.cloud["accuracy_median_m"].as_f64().unwrap(), acc.cloud_relative["accuracy_median_m"].as_f64().unwrap());
    assert!(rel_m <= abs_m + 1e-9 && rel_m < 0.5, "cloud median {abs_m} m absolute, {rel_m} m relative");
    assert!(acc.dsm.count > 0 && acc.dsm_relative.count > 0);
    assert_eq!(acc.stages.len(), Stage::ALL.len());
    assert!(acc.direct.is_none());
    // The terrain stage's products judged against the true bare earth and the scene's trees.
    let dtm = acc.dtm.as_ref().expect("the DTM judged");
    assert!(dtm.count > 0 && dtm.median_abs_m.is_finite(), "{dtm:?}");
    let trees = acc.trees.as_ref().expect("the trees judged");
    assert!(trees["known"].as_u64().unwrap() > 0 && trees["found"].is_u64(), "{trees}");
    let terrain = &rec(Stage::Terrain)["summary"];
    assert!(terrain["dtm"]["ground"].as_u64().unwrap() > 0, "{terrain}");
    // With ground control the products are judged as delivered: no shift is removed, and the points took the
    // simulated datum shift out (about a metre in every fix).
    assert!(acc.ground_control.is_some() && acc.datum_shift_m == [0.0; 3]);
    let delivered = acc.cloud_absolute["accuracy_median_m"].as_f64().unwrap();
    assert!(delivered < 0.5, "cloud as delivered: median {delivered} m from the true surface");

    // The report: every section, every number finite, every image decodes.
    let html = std::fs::read_to_string(project.join("report.html")).unwrap();
    let (images, sections, words) = parse_report(&html);
    for want in ["stages", "import", "registration", "poses", "products", "terrain", "accuracy", "cloud"] {
        assert!(sections.iter().any(|s| s == want), "section {want} missing: {sections:?}");
    }
    assert!(images.len() >= 4, "camera positions, hillshade, ortho and NDVI: {images:?}");
    for w in &words {
        let l = w.to_ascii_lowercase();
        assert!(
            !(l == "nan" || l == "inf" || l == "-inf" || l.contains("nan ")),
            "a non-finite number in the report: {w}"
        );
        if let Ok(v) = w.parse::<f64>() {
            assert!(v.is_finite(), "{w}");
        }
    }
    assert!(words.iter().any(|w| w == "PSNR"), "the held-out table");
    assert!(
        html.contains("Ground control")
            && html.contains("datum shift, found by the points")
            && html.contains("Bundle adjustment on the control points"),
        "GCP section"
    );
    assert!(html.contains("planned host memory") && html.contains("measured (photometric support)"));

    // A rerun: every stage current, nothing rewritten.
    let stamp = std::fs::metadata(products.join("dsm.tif")).unwrap().modified().unwrap();
    let s = process(&o, &mut |_| {}).unwrap();
    assert!(statuses(&s).iter().all(|(_, st)| st == "current"), "{:?}", statuses(&s));
    assert_eq!(std::fs::metadata(products.join("dsm.tif")).unwrap().modified().unwrap(), stamp);

    // An output edited by hand stops the run, naming the file; restored, the run goes on.
    let check = project.join("check.json");
    let original = std::fs::read(&check).unwrap();
    std::fs::write(&check, b"{}").unwrap();
    let e = process(&o, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("check.json") && e.contains("check"), "{e}");
    std::fs::write(&check, original).unwrap();

    // Poses from another tool (`--poses`): the COLMAP model this run made, imported instead of running COLMAP.
    let other = t.path().join("project-poses");
    let model = project.join("dataset/colmap/sparse/0");
    let with_poses = ProcessOptions {
        project: other.clone(),
        poses: Some((msnerf::poses::PoseFormat::Colmap, model)),
        stop_after: Some(Stage::Check),
        ..o.clone()
    };
    let s = process(&with_poses, &mut |_| {}).unwrap();
    assert!(statuses(&s).iter().all(|(st, status)| (*st <= Stage::Check) == (status == "ran")), "{:?}", statuses(&s));
    let poses = rec_of(&other, Stage::Poses);
    assert_eq!(poses["summary"]["registered"], 30, "{poses}");

    // --redo survey: the survey and the report again, nothing before them.
    let s = process(&Stage::Survey.redo_of(o), &mut |_| {}).unwrap();
    let st = statuses(&s);
    for (stage, status) in st {
        let want = if stage >= Stage::Survey { "ran" } else { "current" };
        assert_eq!(status, want, "{stage:?}");
    }
}

trait Redo {
    fn redo_of(self, o: ProcessOptions) -> ProcessOptions;
}

impl Redo for Stage {
    fn redo_of(self, o: ProcessOptions) -> ProcessOptions {
        ProcessOptions { redo: Some(self), ..o }
    }
}
