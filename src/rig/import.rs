//! `msnerf import rig`: a folder of raw single-band rig TIFFs -> a calibrated, registered msnerf dataset.
//!
//! Flow: scan and group ([`super::capture`]) -> irradiance per band from panel captures or the DLS
//! ([`super::calibrate`]) -> per capture, in parallel over CPU threads: raw -> radiance ([`super::radiometry`])
//! -> reflectance -> one resampling per band that undistorts into the reference band's pinhole camera and
//! applies the band's registration homography ([`super::lens`], [`super::register`]) -> crop to the area every
//! band covers -> one float32 multi-band TIFF. `transforms.json` (per-frame intrinsics after the crop, bands
//! with wavelengths, GPS and time, pose priors from GPS), `import_report.json` and `panel_report.json` are written
//! into a staging folder that is renamed onto `--out` only when everything succeeded; the input folder is only read.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde_json::json;

use super::calib::BandFile;
use super::calibrate::{calibrate_panels, dls_irradiance, PanelReport};
use super::capture::{list_tiffs, scan_files, Capture, Skipped};
use super::error::RigError;
use super::frame::{
    estimate_warps, intersect, load, median_warps, rig_only_warps, target_for, valid_rect, write_frame,
    BandRegistration,
};
use super::geo::nadir_pose;
use super::ground_control::{dataset_ground_control, GcpSource};
use super::panel::Quad;
use super::radiometry::radiance_units;
use crate::geo::Projector;
use crate::util::staging::StagingDir;

/// What the output holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    Reflectance,
    Radiance,
}

/// Where irradiance comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum IrradianceSource {
    /// Panel captures when `--panel` is given, else the DLS.
    Auto,
    Panel,
    Dls,
}

/// How bands are registered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Registration {
    /// Per capture up to 24 captures, shared rig warps above.
    Auto,
    /// Every capture aligned on its own.
    Capture,
    /// One warp per band for the whole flight (the median over `--register-sample` captures), as ODM computes one
    /// alignment matrix per band: a rigid rig at flight altitude does not change between triggers.
    Rig,
    /// The rig data alone (XMP `RigRelatives` / DJI relative optical centres), no image alignment.
    None,
}

/// Captures the shared rig warps are estimated on by default (`--register-sample`).
pub const REGISTER_SAMPLE: usize = 8;

/// Flights with more captures than this share the rig's warps under `--register auto`.
pub const RIG_REGISTRATION_ABOVE: usize = 24;

/// Runs `f(0..n)` on `threads` worker threads, in index order of the results; the first error wins.
fn par_map<T: Send>(
    n: usize,
    threads: usize,
    bar: &indicatif::ProgressBar,
    f: impl Fn(usize) -> Result<T, RigError> + Sync,
) -> Result<Vec<T>, RigError> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<T, RigError>>>> = Mutex::new((0..n).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..threads.min(n).max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n {
                    break;
                }
                let r = f(i);
                let failed = r.is_err();
                results.lock().expect("results")[i] = Some(r);
                bar.inc(1);
                if failed {
                    next.store(n, Ordering::Relaxed);
                }
            });
        }
    });
    let mut out = Vec::with_capacity(n);
    for r in results.into_inner().expect("results").into_iter().flatten() {
        out.push(r?);
    }
    Ok(out)
}

/// Options of an import.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    pub input: PathBuf,
    pub out: PathBuf,
    pub panel_files: Vec<PathBuf>,
    /// One value for every band, or one per band in wavelength order.
    pub panel_reflectance: Vec<f64>,
    pub panel_corners: Option<Quad>,
    pub irradiance: IrradianceSource,
    pub units: Units,
    pub undistort: bool,
    pub registration: Registration,
    /// Captures the shared rig warps are estimated on.
    pub register_sample: usize,
    /// Reference band name (default: the band nearest 560 nm, as ODM picks green).
    pub reference_band: Option<String>,
    /// Projected CRS of the GPS pose priors (default: the WGS 84 UTM zone of the first capture with GPS).
    pub crs: Option<crate::geo::Crs>,
    pub overwrite: bool,
    pub threads: usize,
    pub progress: bool,
    /// Keep every band in its own camera and write `rig_cameras` (rig-aware training) instead of registering the
    /// bands ([`super::rig_model`]).
    pub rig_cameras: bool,
    /// Ground control points ([`super::ground_control`]).
    pub ground_control: GcpSource,
}

impl ImportOptions {
    /// An import of `input` into `out` with the command's defaults: irradiance from the panel or the light sensor,
    /// reflectance, undistorted and registered bands (warps shared over [`REGISTER_SAMPLE`] captures when the rig
    /// allows), the reference band nearest 560 nm, the UTM zone of the GPS, the input folder's `gcp_list.txt` when it
    /// has one, one thread, no overwrite, no progress.
    pub fn new(input: impl Into<PathBuf>, out: impl Into<PathBuf>) -> ImportOptions {
        ImportOptions {
            input: input.into(),
            out: out.into(),
            panel_files: Vec::new(),
            panel_reflectance: Vec::new(),
            panel_corners: None,
            irradiance: IrradianceSource::Auto,
            units: Units::Reflectance,
            undistort: true,
            registration: Registration::Auto,
            register_sample: REGISTER_SAMPLE,
            reference_band: None,
            crs: None,
            overwrite: false,
            threads: 1,
            progress: false,
            rig_cameras: false,
            ground_control: GcpSource::Auto,
        }
    }
}

/// The summary of an import.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ImportSummary {
    pub captures: usize,
    pub bands: Vec<String>,
    pub units: Units,
    pub calibration: String,
    pub skipped: Vec<Skipped>,
    pub warnings: Vec<String>,
    pub seconds: f64,
    pub captures_per_second: f64,
    /// Largest registration residual over all captures and bands (pixels; over the sampled captures when the
    /// rig's warps are shared).
    pub max_residual_px: f64,
    /// How bands were registered (`auto` resolved).
    pub registration: Registration,
    /// Shared rig warps: per band, the largest distance between a sampled capture's own warp and the median.
    pub rig_spread_px: Option<Vec<f64>>,
    pub panel: Option<PanelReport>,
}

fn reference_index(bands: &[BandFile], name: Option<&str>) -> Result<usize, RigError> {
    match name {
        Some(n) => bands.iter().position(|b| b.band_name.eq_ignore_ascii_case(n)).ok_or_else(|| {
            let names: Vec<&str> = bands.iter().map(|b| b.band_name.as_str()).collect();
            RigError::option("--reference-band", format!("no band {n:?} (bands: {})", names.join(", ")))
        }),
        None => Ok((0..bands.len())
            .min_by(|&a, &b| (bands[a].center_nm - 560.0).abs().total_cmp(&(bands[b].center_nm - 560.0).abs()))
            .unwrap_or(0)),
    }
}

/// Reads the scan of the panel files (whole captures).
fn panel_captures(files: &[PathBuf]) -> Result<Vec<Capture>, RigError> {
    if files.is_empty() {
        return Ok(Vec::new());
    }
    let scan = scan_files(files)?;
    if scan.captures.is_empty() {
        let why = scan.skipped.iter().map(|s| format!("{}: {}", s.what, s.reason)).collect::<Vec<_>>().join("; ");
        return Err(RigError::option("--panel", format!("no complete panel capture ({why})")));
    }
    Ok(scan.captures)
}

/// Runs an import. Returns its summary (also written as `import_report.json`).
pub fn import_rig(opts: &ImportOptions) -> Result<ImportSummary, RigError> {
    let t0 = Instant::now();
    if !opts.input.is_dir() {
        return Err(RigError::option("DIR", format!("{} is not a folder", opts.input.display())));
    }
    let files = list_tiffs(&opts.input)?;
    // Ground control, read before any work so that a bad file stops the import at once.
    let gcp_list = (opts.ground_control.path(&opts.input))
        .map(|p| crate::geo::gcp::read_gcp_list(&p))
        .transpose()
        .map_err(|e| RigError::option("--gcp", e.to_string()))?;
    if gcp_list.is_some() && opts.rig_cameras {
        return Err(RigError::option(
            "--gcp",
            "ground control is carried into registered frames only: leave out --rig-cameras or pass --no-gcp",
        ));
    }
    // Panel files given by path: the whole capture of each, whether inside DIR or not.
    let mut panels = panel_captures(&opts.panel_files)?;
    if !panels.is_empty() {
        // Complete the panel captures with their other bands from DIR.
        let keys: Vec<String> = panels.iter().map(|c| c.key.clone()).collect();
        let all = scan_files(&files)?;
        for c in all.captures.iter().filter(|c| keys.contains(&c.key)) {
            if let Some(p) = panels.iter_mut().find(|p| p.key == c.key) {
                if c.bands.len() > p.bands.len() {
                    *p = c.clone();
                }
            }
        }
    }
    let panel_keys: Vec<String> = panels.iter().map(|c| c.key.clone()).collect();
    let mut scan = scan_files(&files)?;
    scan.captures.retain(|c| !panel_keys.contains(&c.key));
    scan.skipped.retain(|s| s.capture.as_ref().is_none_or(|k| !panel_keys.contains(k)));
    if scan.captures.is_empty() {
        let why = scan.skipped.iter().map(|s| format!("{}: {}", s.what, s.reason)).collect::<Vec<_>>().join("; ");
        return Err(RigError::option("DIR", format!("no complete flight capture in {} ({why})", opts.input.display())));
    }
    let ref_idx = reference_index(&scan.captures[0].bands, opts.reference_band.as_deref())?;
    let mut warnings = Vec::new();
    let mut auto_panels = false;
    if opts.panel_files.is_empty() {
        // Panel captures taken on the ground among the flight's: found, kept out of the flight.
        let split = super::panels::split_panel_captures(std::mem::take(&mut scan.captures), ref_idx)?;
        scan.captures = split.flight;
        for (name, why) in split.left_out {
            scan.skipped.push(Skipped { capture: Some(name.clone()), what: format!("capture {name}"), reason: why });
        }
        warnings.extend(split.warnings);
        auto_panels = !split.panels.is_empty();
        panels = split.panels;
        if scan.captures.is_empty() {
            return Err(RigError::option("DIR", "every capture is a panel or ground capture: no flight to import"));
        }
    }
    if !scan.thermal.is_empty() {
        let (_, band) = &scan.thermal[0];
        warnings.push(format!(
            "{} thermal band file(s) ({band}) left out: msnerf trains on the reflective bands",
            scan.thermal.len()
        ));
    }
    let first = &scan.captures[0];
    let nb = first.bands.len();
    if first.bands[ref_idx].lens.is_none() {
        // Without a lens model the frames' intrinsics would be made up: refuse, naming what is missing.
        return Err(RigError::missing(
            &first.bands[ref_idx].meta.path,
            "Camera:PerspectiveFocalLength + Camera:PrincipalPoint (or drone-dji:DewarpData, or EXIF FocalLength with FocalPlaneXResolution)",
            "the reference band's camera model; without it the dataset's intrinsics are unknown",
        ));
    }
    if opts.rig_cameras {
        if !matches!(opts.registration, Registration::Auto | Registration::None) {
            return Err(RigError::option(
                "--rig-cameras",
                "keeps every band in its own camera: it cannot be combined with --register capture or rig",
            ));
        }
        warnings.extend(super::rig_model::check_rig(first)?);
    }

    // Irradiance.
    let panel_names = || panels.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ");
    if auto_panels && opts.panel_reflectance.is_empty() && opts.units == Units::Reflectance {
        if opts.irradiance == IrradianceSource::Panel {
            return Err(RigError::option(
                "--panel-reflectance",
                format!(
                    "panel capture(s) {} found: give the panel's reflectance from its calibration sheet",
                    panel_names()
                ),
            ));
        }
        warnings.push(format!(
            "panel capture(s) {} found but no --panel-reflectance: calibrated from the light sensor; give the \
             panel's reflectance (its calibration sheet) to calibrate from the panel",
            panel_names()
        ));
        panels.clear();
    }
    let source = match (opts.units, opts.irradiance, panels.is_empty()) {
        (Units::Radiance, _, _) => "none",
        (_, IrradianceSource::Panel, true) => {
            return Err(RigError::option(
                "--irradiance panel",
                "needs a panel capture: --panel FILE (a band file of a panel capture), or panel captures taken on \
                 the ground in DIR",
            ))
        }
        (_, IrradianceSource::Panel | IrradianceSource::Auto, false) => "panel",
        (_, IrradianceSource::Dls | IrradianceSource::Auto, _) => "dls",
    };
    let mut panel_report = None;
    let panel_e: Option<Vec<f64>> = if source == "panel" {
        let refl = match opts.panel_reflectance.len() {
            1 => vec![opts.panel_reflectance[0]; nb],
            n if n == nb => opts.panel_reflectance.clone(),
            0 => {
                return Err(RigError::option(
                    "--panel-reflectance",
                    "needed with --panel: the panel's reflectance from its calibration sheet (one value, or one per band by wavelength)",
                ))
            }
            n => return Err(RigError::option("--panel-reflectance", format!("{n} values for {nb} bands"))),
        };
        if let Some(v) = refl.iter().find(|v| !(**v > 0.0 && **v <= 1.0)) {
            return Err(RigError::option("--panel-reflectance", format!("{v} is not a reflectance in (0, 1]")));
        }
        let rep = calibrate_panels(&panels, &refl, opts.panel_corners, &mut warnings)?;
        let e = rep.irradiance.clone();
        panel_report = Some(rep);
        Some(e)
    } else {
        None
    };
    if source == "dls" && opts.irradiance == IrradianceSource::Auto {
        // Fail early and by name when the DLS is missing.
        dls_irradiance(first)
            .map_err(|e| RigError::option("--irradiance", format!("{e}; give --panel or --units radiance")))?;
    }

    let staging = StagingDir::new(&opts.out, opts.overwrite)
        .map_err(|e| RigError::Output { path: opts.out.clone(), reason: e.to_string() })?;
    let images = staging.path.join("images");
    std::fs::create_dir_all(&images).map_err(RigError::io(&images))?;

    let n = scan.captures.len();
    let bar = if opts.progress {
        let b = indicatif::ProgressBar::new(n as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("importing {bar:30} {pos}/{len} captures, {per_sec}, ETA {eta}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let irradiance_of = |cap: &Capture| -> Result<Option<Vec<f64>>, RigError> {
        match source {
            "panel" => Ok(panel_e.clone()),
            "dls" => dls_irradiance(cap).map(Some),
            _ => Ok(None),
        }
    };
    let mode = match opts.registration {
        _ if opts.rig_cameras => Registration::None,
        Registration::Auto if n > RIG_REGISTRATION_ABOVE => Registration::Rig,
        Registration::Auto => Registration::Capture,
        m => m,
    };
    let threads = opts.threads.max(1);
    // Shared rig warps: estimated on captures spread over the flight, the median kept.
    let mut rig_spread_px = None;
    let mut sample_stats: Vec<Vec<BandRegistration>> = Vec::new();
    let shared = if mode == Registration::Rig {
        let k = opts.register_sample.clamp(1, n);
        let picks: Vec<usize> = (0..k).map(|j| (j * n + n / 2) / k).collect();
        let sets = par_map(k, threads, &indicatif::ProgressBar::hidden(), |j| {
            let cap = &scan.captures[picks[j]];
            let l = load(cap, irradiance_of(cap)?.as_deref())?;
            Ok(estimate_warps(cap, &l, ref_idx, opts.undistort, true))
        })?;
        let t = target_for(first, ref_idx, opts.undistort);
        let (warps, spread) = median_warps(&sets, t.width, t.height);
        rig_spread_px = Some(spread);
        sample_stats = sets;
        Some(warps)
    } else {
        None
    };
    // Every capture's warps (estimated per capture, or the shared ones), then the flight's common crop from the
    // warps' geometry alone, so that every frame has one size, then the pixels.
    let warps: Vec<Vec<BandRegistration>> = match (&shared, mode) {
        (Some(w), _) => vec![w.clone(); n],
        (None, Registration::Capture) => par_map(n, threads, &bar, |i| {
            let cap = &scan.captures[i];
            let l = load(cap, irradiance_of(cap)?.as_deref())?;
            Ok(estimate_warps(cap, &l, ref_idx, opts.undistort, true))
        })?,
        (None, _) => scan.captures.iter().map(|c| rig_only_warps(c, ref_idx, opts.undistort)).collect(),
    };
    let mut rect: Option<(usize, usize, usize, usize)> = None;
    for (cap, regs) in scan.captures.iter().zip(&warps) {
        let r = valid_rect(cap, regs, ref_idx, opts.undistort).ok_or_else(|| RigError::Capture {
            capture: cap.key.clone(),
            reason: "the bands share no common area after registration".into(),
        })?;
        rect = match rect {
            None => Some(r),
            Some(a) => Some(intersect(a, r).ok_or_else(|| RigError::Capture {
                capture: cap.key.clone(),
                reason: "its bands' common area does not overlap the other captures'".into(),
            })?),
        };
    }
    let rect = rect.expect("at least one capture");
    bar.set_position(0);
    let frames = par_map(n, threads, &bar, |i| {
        let cap = &scan.captures[i];
        let l = load(cap, irradiance_of(cap)?.as_deref())?;
        if opts.rig_cameras {
            super::rig_model::write_frame_rig(cap, &l, ref_idx, opts.undistort, &staging.path)
        } else {
            write_frame(cap, &l, warps[i].clone(), ref_idx, opts.undistort, rect, &staging.path)
        }
    })?;
    bar.finish_and_clear();

    // transforms.json.
    let bands_json: Vec<_> = first
        .bands
        .iter()
        .map(|b| json!({"name": b.band_name, "center_nm": b.center_nm, "fwhm_nm": b.fwhm_nm}))
        .collect();
    let origin = scan.captures.iter().find_map(|c| c.bands[ref_idx].meta.gps);
    // GPS pose priors in a projected CRS: the one asked for, or the first GPS fix's UTM zone.
    let projector = match (origin, &opts.crs) {
        (None, _) => None,
        (Some(_), Some(c)) => Some(Projector::new(c)),
        (Some(o), None) => Some(crate::geo::Crs::utm_for(o.latitude, o.longitude).and_then(|c| Projector::new(&c))),
    }
    .transpose()
    .map_err(|e| RigError::Option { key: "--crs".into(), reason: e.to_string() })?;
    // Pose priors: the GPS fix projected, the heading from the attitude; captures without a fix get the mean of
    // the others' positions (named in the warnings), not a place the fix never gave.
    let (gps_warn, no_fix) = super::flight_checks::gps_warnings(&scan.captures, ref_idx);
    warnings.extend(gps_warn);
    let mut priors = Vec::with_capacity(n);
    for cap in &scan.captures {
        let m = &cap.bands[ref_idx].meta;
        let yaw = m.xmp.number("dji.com", "GimbalYawDegree").or(m.xmp.number("pix4d.com", "Yaw")).unwrap_or(0.0);
        priors.push(match (&projector, m.gps) {
            (Some(p), Some(g)) => {
                let proj_err = |e: crate::geo::CrsError| RigError::Capture {
                    capture: cap.key.clone(),
                    reason: format!("GPS position: {e}"),
                };
                let pos = p.from_geodetic(g.latitude, g.longitude, g.altitude.unwrap_or(0.0)).map_err(proj_err)?;
                // The yaw is from true north; the grid's north is off by the meridian convergence.
                (Some(pos), yaw - p.convergence_deg(g.latitude, g.longitude).map_err(proj_err)?)
            }
            _ => (None, yaw),
        });
    }
    let fixes: Vec<[f64; 3]> = priors.iter().filter_map(|p| p.0).collect();
    let mean_fix = if fixes.is_empty() {
        [0.0; 3]
    } else {
        [0, 1, 2].map(|i| fixes.iter().map(|p| p[i]).sum::<f64>() / fixes.len() as f64)
    };
    let mut frames_json = Vec::with_capacity(n);
    for ((cap, f), prior) in scan.captures.iter().zip(&frames).zip(&priors) {
        let m = &cap.bands[ref_idx].meta;
        let (pos, heading) = (prior.0.unwrap_or(mean_fix), prior.1);
        let mut frame = json!({
            "file_path": f.file,
            "transform_matrix": nadir_pose(pos, heading),
            "fl_x": f.fx, "fl_y": f.fx,
            "cx": f.cx + 0.5, "cy": f.cy + 0.5,
            "w": f.width, "h": f.height,
            "capture_id": cap.key,
            "time": m.datetime,
            "gps": m.gps,
            "gps_rejected": m.gps_rejected,
            "source_files": cap.bands.iter().map(|b| b.meta.path.display().to_string()).collect::<Vec<_>>(),
            "registration_residual_px": f.registration.iter().map(|r| r.stats.map(|s| s.residual_px)).collect::<Vec<_>>(),
        });
        if opts.rig_cameras {
            frame["mask_path"] = json!(format!("masks/{}.png", cap.name()));
        }
        if !opts.undistort {
            if let Some(l) = cap.bands[ref_idx].lens {
                frame["camera_model"] = json!("OPENCV");
                frame["fl_x"] = json!(l.fx);
                frame["fl_y"] = json!(l.fy);
                // The raw camera's principal point moved by the crop (f.cx, f.cy are -x0, -y0 here).
                frame["cx"] = json!(l.cx + f.cx + 0.5);
                frame["cy"] = json!(l.cy + f.cy + 0.5);
                frame["k1"] = json!(l.k1);
                frame["k2"] = json!(l.k2);
                frame["k3"] = json!(l.k3);
                frame["p1"] = json!(l.p1);
                frame["p2"] = json!(l.p2);
            }
        }
        frames_json.push(frame);
    }
    let calibration: Vec<_> = first
        .bands
        .iter()
        .enumerate()
        .map(|(bi, b)| {
            json!({
                "band": b.band_name,
                "radiance": radiance_units(b),
                "source": source,
                "irradiance": panel_e.as_ref().map(|e| e[bi]),
                "light_sensor": (source == "dls").then(|| super::calibrate::band_dls(b).ok().map(|d| d.1)).flatten(),
            })
        })
        .collect();
    let transforms = json!({
        "camera_model": if opts.undistort { "PINHOLE" } else { "OPENCV" },
        "bands": bands_json,
        "units": opts.units,
        "calibration": calibration,
        "reference_band": first.bands[ref_idx].band_name,
        "pose_prior": {
            "source": "gps",
            "frame": match &projector {
                Some(p) => format!("{}: easting, northing, ellipsoidal height (metres); nadir cameras, heading from the \
                                    gimbal yaw when the files carry it, turned by the meridian convergence", p.crs.describe()),
                None => "no GPS in the files: every camera at the origin".to_string(),
            },
            "origin": origin,
            "note": "priors only: import poses from SfM (or run it) before training a real flight",
        },
        "frames": frames_json,
    });
    let mut transforms = transforms;
    if let Some(p) = &projector {
        transforms["crs"] = json!(p.crs.key());
    }
    if opts.rig_cameras {
        transforms["rig_cameras"] = super::rig_model::rig_cameras_json(first, ref_idx, opts.undistort);
    }
    if let Some(list) = &gcp_list {
        // The dataset's CRS is the GPS's; without GPS, the GCPs' own (their UTM zone when they are geographic).
        let crs = match &projector {
            Some(p) => p.crs.clone(),
            None if list.crs.kind == crate::geo::CrsKind::Projected => list.crs.clone(),
            None => {
                let p = &list.points[0].xyz;
                crate::geo::Crs::utm_for(p[1], p[0]).map_err(|e| RigError::option("--gcp", e.to_string()))?
            }
        };
        transforms["ground_control"] =
            dataset_ground_control(list, &crs, &scan.captures, &frames, ref_idx, opts.undistort, &mut warnings)?;
        transforms["crs"] = json!(crs.key());
    }
    let tpath = staging.path.join("transforms.json");
    // What is written must load: the dataset's own parser checks it (intrinsics, poses, bands) first.
    crate::data::transforms::parse_value(&tpath, &transforms).map_err(|e| RigError::Output {
        path: opts.out.join("transforms.json"),
        reason: format!("the dataset would not load, nothing was written: {e}"),
    })?;
    let text = serde_json::to_string_pretty(&transforms).expect("json");
    std::fs::write(&tpath, text).map_err(RigError::io(&tpath))?;

    // Flight-level checks: reflectance that is implausible for a whole flight, bands left unaligned.
    let band_names: Vec<String> = first.bands.iter().map(|b| b.band_name.clone()).collect();
    if opts.units == Units::Reflectance {
        for (bi, name) in band_names.iter().enumerate() {
            let per: Vec<[f32; 2]> = frames.iter().map(|f| f.value_quantiles[bi]).collect();
            if let Some((median, p99)) = super::flight_checks::flight_quantiles(&per) {
                warnings.extend(super::flight_checks::reflectance_problem(name, median, p99));
            }
        }
    }
    let worst: Vec<Option<(f64, String)>> = (0..nb)
        .map(|bi| {
            scan.captures
                .iter()
                .zip(&frames)
                .filter_map(|(c, f)| f.registration[bi].stats.map(|s| (s.residual_px, c.name())))
                .max_by(|a, b| a.0.total_cmp(&b.0))
        })
        .collect();
    warnings.extend(super::flight_checks::registration_warnings(&band_names, &worst, rig_spread_px.as_deref()));
    let seconds = t0.elapsed().as_secs_f64();
    let max_residual_px = frames
        .iter()
        .map(|f| &f.registration)
        .chain(sample_stats.iter())
        .flat_map(|regs| regs.iter().filter_map(|r| r.stats.map(|s| s.residual_px)))
        .fold(0.0, f64::max);
    let summary = ImportSummary {
        captures: n,
        bands: first.bands.iter().map(|b| b.band_name.clone()).collect(),
        units: opts.units,
        calibration: source.into(),
        skipped: scan.skipped.clone(),
        warnings,
        seconds,
        captures_per_second: n as f64 / seconds.max(1e-9),
        max_residual_px,
        registration: mode,
        rig_spread_px,
        panel: panel_report,
    };
    let report =
        json!({"summary": summary, "frames": frames, "rig_samples": sample_stats, "captures_without_gps": no_fix});
    let rpath = staging.path.join("import_report.json");
    std::fs::write(&rpath, serde_json::to_string_pretty(&report).expect("json")).map_err(RigError::io(&rpath))?;
    if let Some(p) = &summary.panel {
        let ppath = staging.path.join("panel_report.json");
        std::fs::write(&ppath, serde_json::to_string_pretty(p).expect("json")).map_err(RigError::io(&ppath))?;
    }
    staging.commit().map_err(|e| RigError::Output { path: opts.out.clone(), reason: e.to_string() })?;
    Ok(summary)
}
