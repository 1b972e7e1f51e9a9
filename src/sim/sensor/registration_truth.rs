//! Band-registration accuracy of an imported raw flight, measured against the simulator's truth
//! ([`evaluate_registration`]).
//!
//! Inputs: a raw flight written by `msnerf simulate --raw-rig` (its `card/` and `truth/flight.json`) and the
//! dataset `msnerf import rig` made of that card (`transforms.json`, or `transforms.import.json` where `msnerf process`
//! kept the import's own beside the posed one; `import_report.json`). The flight's geometry
//! is rebuilt from the truth's scene name, sensor, image size, seed and number of flight captures
//! ([`super::flight::prepare`]) and checked against the poses the truth recorded.
//!
//! Conventions:
//! - A sample is a target pixel (x, y) of the importer's target camera (the reference band's undistorted pinhole,
//!   uncropped pixel coordinates, centres at integers) on a `grid` x `grid` lattice of cell centres inside the
//!   dataset's crop. Its **error** in band b is `|source_pixel(target, lens_b, warp_b, x, y) - truth|` in raw
//!   pixels of band b: where the importer samples band b's raw image for that pixel against where the scene
//!   point seen there really lies in it ([`super::truth::band_correspondence`], parallax between the band
//!   cameras included). The lenses are the ones the importer reads from the files.
//! - Per band: `median_px` and `p95_px` over every sample of every evaluated capture; `spread_px` = the 95th
//!   percentile over captures of each capture's median error (how far a capture can be off as a whole: a bias
//!   shared by every capture shows here as much as a scatter between captures); `worst_capture_px` the largest
//!   capture median.
//! - `floor_*`: the same errors of the per-capture homography that best fits the truth itself on the same samples
//!   (least squares reweighted towards the least absolute error, so it follows the samples' majority, as the
//!   median does): what a homography cannot represent (the parallax of scene relief between band cameras a few
//!   centimetres apart, and lens-model rounding in the files), the floor a pure homography would meet.
//! - Panel captures (the truth's `kind: panel`) are left out and listed in `skipped`.
//! - Percentiles interpolate linearly between order statistics (numpy's default).
//!
//! Bands are matched by name between the camera profile (file-suffix order) and the dataset (wavelength order).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::flight::{prepare, RawRigOptions};
use super::forward::undistort;
use super::profile::{SensorKind, SensorProfile};
use super::truth::{band_correspondence, Correspondence};
use crate::rig::calib::Lens;
use crate::rig::capture::{list_tiffs, scan_files, Capture};
use crate::rig::frame::target_for;
use crate::rig::lens::{source_pixel, Target};
use crate::rig::register::{fit_homography, fit_homography_weighted, Homography, PointPair};
use crate::rig::warp::Warp;
use crate::rig::RigError;
use crate::sim::{Prepared, SceneDesc, SimError};
use crate::util::stats::quantile_of_sorted as percentile_sorted;

/// Why an evaluation could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RegistrationTruthError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// A file that does not hold what it should (`reason` names the key).
    #[error("{}: {reason}", path.display())]
    Format { path: PathBuf, reason: String },
    /// The dataset and the raw flight do not belong together, or the flight cannot be rebuilt.
    #[error("the import does not match the raw flight: {0}")]
    Mismatch(String),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(transparent)]
    Rig(#[from] RigError),
}

/// Options of an evaluation.
#[derive(Debug, Clone)]
pub struct RegistrationTruthOptions {
    /// Samples per axis over the crop (`grid` x `grid` per capture and band).
    pub grid: usize,
    /// The scene the flight was simulated from, when `truth/flight.json`'s scene name is not a built-in scene.
    pub scene: Option<SceneDesc>,
}

impl Default for RegistrationTruthOptions {
    fn default() -> Self {
        RegistrationTruthOptions { grid: 20, scene: None }
    }
}

/// One band's accuracy (raw pixels of the band).
#[derive(Debug, Clone, Serialize)]
pub struct BandAccuracy {
    pub band: String,
    /// Median error over every sample of every capture.
    pub median_px: f64,
    /// 95th percentile of the same.
    pub p95_px: f64,
    /// 95th percentile over captures of each capture's median error.
    pub spread_px: f64,
    /// The largest capture median, and its capture (file stem).
    pub worst_capture_px: f64,
    pub worst_capture: String,
    /// Median and 95th percentile error of the best per-capture homography fitted to the truth.
    pub floor_median_px: f64,
    pub floor_p95_px: f64,
    /// Samples with a truth (a ray that hits the scene and lands in front of the band camera).
    pub samples: usize,
}

/// One capture's median error per band (the order of [`RegistrationAccuracy::bands`]).
#[derive(Debug, Clone, Serialize)]
pub struct CaptureAccuracy {
    pub capture: String,
    pub view: usize,
    pub median_px: Vec<f64>,
}

/// A capture of the dataset left out of the evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct SkippedCapture {
    pub capture: String,
    pub reason: String,
}

/// The registration accuracy of an import ([`evaluate_registration`]).
#[derive(Debug, Clone, Serialize)]
pub struct RegistrationAccuracy {
    pub scene: String,
    pub sensor: SensorKind,
    pub width: u32,
    pub height: u32,
    pub reference_band: String,
    /// How the import registered the bands (`import_report.json`'s `summary.registration`).
    pub registration: String,
    pub undistort: bool,
    /// The dataset's crop in target pixels (x0, y0, x1, y1), end exclusive.
    pub crop: [usize; 4],
    pub grid: usize,
    /// Captures evaluated.
    pub captures: usize,
    pub skipped: Vec<SkippedCapture>,
    /// Every band of the dataset, in its order (the reference band included: its error is the undistortion's).
    pub bands: Vec<BandAccuracy>,
    pub per_capture: Vec<CaptureAccuracy>,
}

impl RegistrationAccuracy {
    /// The acceptance check: one line per band whose median exceeds `max_median_px` or whose spread exceeds
    /// `max_spread_px` (empty when every band passes).
    pub fn failures(&self, max_median_px: f64, max_spread_px: f64) -> Vec<String> {
        let mut out = Vec::new();
        for b in &self.bands {
            if b.median_px.is_nan() || b.median_px > max_median_px {
                out.push(format!("{}: median {:.3} px > {max_median_px} px", b.band, b.median_px));
            }
            if b.spread_px.is_nan() || b.spread_px > max_spread_px {
                out.push(format!(
                    "{}: spread {:.3} px > {max_spread_px} px (worst capture {} at {:.3} px)",
                    b.band, b.spread_px, b.worst_capture, b.worst_capture_px
                ));
            }
        }
        if self.captures == 0 {
            out.push("no capture evaluated".into());
        }
        out
    }

    /// A plain-text table, one line per band.
    pub fn table(&self) -> String {
        let mut s = format!(
            "registration vs truth: scene {}, {} {}x{}, {} captures, registration {}, grid {}x{}\n\
             {:<10} {:>8} {:>8} {:>8} {:>8} {:>10} {:>10}\n",
            self.scene,
            self.sensor.name(),
            self.width,
            self.height,
            self.captures,
            self.registration,
            self.grid,
            self.grid,
            "band",
            "median",
            "p95",
            "spread",
            "worst",
            "floor med",
            "floor p95"
        );
        for b in &self.bands {
            s += &format!(
                "{:<10} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>10.3} {:>10.3}\n",
                b.band, b.median_px, b.p95_px, b.spread_px, b.worst_capture_px, b.floor_median_px, b.floor_p95_px
            );
        }
        s
    }
}

#[derive(Deserialize)]
struct FlightRecord {
    scene: String,
    seed: u64,
    sensor: SensorKind,
    width: u32,
    height: u32,
    world_offset: [f64; 3],
    captures: Vec<CaptureTruth>,
}

#[derive(Deserialize)]
struct CaptureTruth {
    kind: String,
    view: Option<usize>,
    capture_id: String,
    reference_c2w: Option<[[f64; 4]; 4]>,
}

#[derive(Deserialize)]
struct Report {
    summary: ReportSummary,
    frames: Vec<ReportFrame>,
}

#[derive(Deserialize)]
struct ReportSummary {
    registration: String,
}

#[derive(Deserialize)]
struct ReportFrame {
    capture: String,
    file: String,
    width: usize,
    height: usize,
    cx: f64,
    cy: f64,
    registration: Vec<ReportBand>,
}

#[derive(Deserialize)]
struct ReportBand {
    band: String,
    warp: Warp,
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, RegistrationTruthError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| RegistrationTruthError::Io { path: path.into(), source })?;
    serde_json::from_str(&text).map_err(|e| RegistrationTruthError::Format { path: path.into(), reason: e.to_string() })
}

fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v
}

/// Where a band's warp operates: the band's target pixels (its raw pixel undistorted into the target camera) when
/// the import undistorted, its raw pixels otherwise.
fn warp_coords(target: &Target, lens: Option<&Lens>, (u, v): (f64, f64)) -> (f64, f64) {
    match lens {
        None => (u, v),
        Some(l) => {
            let (x, y) = undistort(l, (u - l.cx) / l.fx, (v - l.cy) / l.fy);
            (target.f * x + target.cx, target.f * y + target.cy)
        }
    }
}

/// A raw flight's truth, rebuilt for registration questions: the camera, the flight's geometry (checked against the
/// poses the truth recorded) and the card's captures as the importer reads them.
pub struct FlightTruth {
    pub scene: String,
    pub sensor: SensorKind,
    pub width: u32,
    pub height: u32,
    profile: SensorProfile,
    prep: Prepared,
    captures: Vec<CaptureTruth>,
    card: Vec<Capture>,
}

/// A capture's errors in one band, per sample (raw pixels of the band): the warp's and the floor's (the best
/// homography fitted to the truth on the same samples; NaN where no fit could be made).
#[derive(Debug, Clone, Default)]
pub struct SampleErrors {
    pub errors: Vec<f64>,
    /// The same as vectors (where the warp samples minus the truth, raw pixels x and y).
    pub vectors: Vec<[f64; 2]>,
    pub floor: Vec<f64>,
}

/// How a capture's band is asked about: the dataset's reference band and whether the import undistorted, the crop
/// `[x0, y0, x1, y1)` in target pixels and the samples per axis.
#[derive(Debug, Clone)]
pub struct Question<'a> {
    pub reference_band: &'a str,
    pub undistorted: bool,
    pub crop: [usize; 4],
    pub grid: usize,
}

impl FlightTruth {
    /// Reads `raw/truth/flight.json`, rebuilds the flight (`scene`: the scene it was simulated from, when the
    /// truth's scene name is not a built-in) and scans `raw/card`.
    pub fn open(raw: &Path, scene: Option<&SceneDesc>) -> Result<FlightTruth, RegistrationTruthError> {
        let mismatch = RegistrationTruthError::Mismatch;
        let truth_path = raw.join("truth").join("flight.json");
        let truth: FlightRecord = read_json(&truth_path)?;
        let desc = match scene {
            Some(d) => d.clone(),
            None => SceneDesc::load(&truth.scene)?,
        };
        if desc.name != truth.scene {
            return Err(mismatch(format!(
                "the flight is of scene `{}`, the scene given is `{}`",
                truth.scene, desc.name
            )));
        }
        let flights = truth.captures.iter().filter(|c| c.kind == "flight").count();
        let ro = RawRigOptions {
            sensor: truth.sensor,
            width: Some(truth.width),
            height: Some(truth.height),
            views: Some(flights),
            seed: Some(truth.seed),
            threads: 1,
            points: 1000,
            ..RawRigOptions::default()
        };
        let (profile, _, prep, _) = prepare(&desc, &ro)?;
        // The rebuilt flight must be the one written.
        for c in truth.captures.iter().filter(|c| c.kind == "flight") {
            let (Some(v), Some(m)) = (c.view, c.reference_c2w) else {
                return Err(RegistrationTruthError::Format {
                    path: truth_path.clone(),
                    reason: format!("flight capture {} without `view` or `reference_c2w`", c.capture_id),
                });
            };
            let p = prep.poses.get(v).ok_or_else(|| mismatch(format!("view {v} beyond the rebuilt flight")))?;
            let off = (0..3)
                .flat_map(|i| (0..4).map(move |j| (i, j)))
                .map(|(i, j)| (p[i][j] + if j == 3 { truth.world_offset[i] } else { 0.0 } - m[i][j]).abs())
                .fold(0.0, f64::max);
            if off.is_nan() || off >= 1e-6 {
                return Err(mismatch(format!(
                    "view {v}: the rebuilt pose is {off:.3e} off the recorded one (scene or options changed since)"
                )));
            }
        }
        let card = scan_files(&list_tiffs(&raw.join("card"))?)?.captures;
        Ok(FlightTruth {
            scene: truth.scene,
            sensor: truth.sensor,
            width: truth.width,
            height: truth.height,
            profile,
            prep,
            captures: truth.captures,
            card,
        })
    }

    /// The card's capture with this capture id (as the importer reads it).
    pub fn capture(&self, key: &str) -> Option<&Capture> {
        self.card.iter().find(|c| c.key == key)
    }

    /// The flight view of a capture id: `Ok(None)` for a panel capture, an error for an id the truth lacks.
    pub fn view_of(&self, key: &str) -> Result<Option<usize>, RegistrationTruthError> {
        let c =
            self.captures.iter().find(|c| c.capture_id == key).ok_or_else(|| {
                RegistrationTruthError::Mismatch(format!("capture {key} is not in the flight's truth"))
            })?;
        Ok(c.view.filter(|_| c.kind == "flight"))
    }

    /// The importer's target camera of a capture (see [`crate::rig::frame::target_for`]).
    pub fn target(&self, key: &str, reference_band: &str, undistorted: bool) -> Result<Target, RegistrationTruthError> {
        let cap = self.card_capture(key)?;
        let ci = band_index(cap, reference_band)?;
        Ok(target_for(cap, ci, undistorted))
    }

    fn card_capture(&self, key: &str) -> Result<&Capture, RegistrationTruthError> {
        self.capture(key).ok_or_else(|| RegistrationTruthError::Mismatch(format!("capture {key} is not on the card")))
    }

    /// The errors of `warp` (band `band` of capture `key`, target pixels -> the band's target pixels, as the
    /// importer writes it) on the question's samples (see the module doc).
    pub fn warp_errors(
        &self,
        key: &str,
        band: &str,
        warp: &Warp,
        q: &Question,
    ) -> Result<SampleErrors, RegistrationTruthError> {
        let mismatch = RegistrationTruthError::Mismatch;
        if q.grid < 3 {
            return Err(mismatch(format!("a grid of {} samples per axis: at least 3", q.grid)));
        }
        if let Some(f) = &warp.field {
            if !f.is_consistent() {
                return Err(mismatch(format!("{key}, band {band}: a shift field whose grid does not hold together")));
            }
        }
        let view = self.view_of(key)?.ok_or_else(|| mismatch(format!("{key} is a panel capture")))?;
        let cap = self.card_capture(key)?;
        let ci_ref = band_index(cap, q.reference_band)?;
        let target = target_for(cap, ci_ref, q.undistorted);
        let [x0, y0, x1, y1] = q.crop;
        if !(x0 + 1 < x1 && y0 + 1 < y1 && x1 <= target.width && y1 <= target.height) {
            return Err(mismatch(format!(
                "{key}: a crop {:?} outside the {}x{} target camera",
                q.crop, target.width, target.height
            )));
        }
        let profile_band = |name: &str| {
            self.profile
                .bands
                .iter()
                .position(|b| b.name.eq_ignore_ascii_case(name))
                .ok_or_else(|| mismatch(format!("band {name} is not a band of the camera")))
        };
        let (p_ref, pb) = (profile_band(q.reference_band)?, profile_band(band)?);
        let lens = cap.bands[band_index(cap, band)?].lens.filter(|_| q.undistorted);
        let ref_lens = cap.bands[ci_ref].lens;
        let (w, h, g) = ((x1 - x0) as f64, (y1 - y0) as f64, q.grid);
        let mut samples = Vec::with_capacity(g * g);
        for j in 0..g {
            for i in 0..g {
                let x = x0 as f64 + (i as f64 + 0.5) * w / g as f64 - 0.5;
                let y = y0 as f64 + (j as f64 + 0.5) * h / g as f64 - 0.5;
                // The question asked of the truth: the target camera's pixel, or (no undistortion) the reference's
                // raw pixel as a normalised undistorted ray.
                let (qx, qy, tq) = if q.undistorted {
                    (x, y, (target.f, target.cx, target.cy))
                } else {
                    let l = ref_lens.ok_or_else(|| {
                        mismatch(format!("{key}: the reference band has no lens model to undistort the truth's rays"))
                    })?;
                    let (xn, yn) = undistort(&l, (x - l.cx) / l.fx, (y - l.cy) / l.fy);
                    (xn, yn, (1.0, 0.0, 0.0))
                };
                let c = Correspondence { view, reference: p_ref, band: pb, target: tq };
                if let Some(t) = band_correspondence(&self.prep, &self.profile, &c, qx, qy) {
                    samples.push(((x, y), t));
                }
            }
        }
        let vectors_of = |w: &Warp| -> Vec<[f64; 2]> {
            samples
                .iter()
                .map(|&((x, y), (u, v))| {
                    let (a, b) = source_pixel(&target, lens.as_ref(), w, x, y);
                    [a - u, b - v]
                })
                .collect()
        };
        let err_of = |w: &Warp| -> Vec<f64> { vectors_of(w).iter().map(|v| v[0].hypot(v[1])).collect() };
        let pairs: Vec<PointPair> = samples.iter().map(|&(p, t)| (p, warp_coords(&target, lens.as_ref(), t))).collect();
        let floor = match robust_homography(&pairs, |h| err_of(&Warp::from_homography(*h))) {
            Some(hf) => err_of(&Warp::from_homography(hf)),
            None => vec![f64::NAN; samples.len()],
        };
        let vectors = vectors_of(warp);
        Ok(SampleErrors { errors: vectors.iter().map(|v| v[0].hypot(v[1])).collect(), vectors, floor })
    }
}

/// The homography that best fits the majority of `pairs`: least squares reweighted towards the least absolute
/// error (weights `1 / max(error, 0.001 px)`, twenty rounds), `errors` giving each pair's error for a homography.
fn robust_homography(pairs: &[PointPair], errors: impl Fn(&Homography) -> Vec<f64>) -> Option<Homography> {
    let mut h = fit_homography(pairs)?;
    for _ in 0..20 {
        let w: Vec<f64> = errors(&h).iter().map(|e| 1.0 / e.max(1e-3)).collect();
        h = fit_homography_weighted(pairs, &w)?;
    }
    Some(h)
}

fn band_index(cap: &Capture, name: &str) -> Result<usize, RegistrationTruthError> {
    cap.bands
        .iter()
        .position(|b| b.band_name.eq_ignore_ascii_case(name))
        .ok_or_else(|| RegistrationTruthError::Mismatch(format!("capture {}: no {name} file on the card", cap.name())))
}

/// Measures the registration of the import in `dataset` of the raw flight in `raw` (see the module doc).
pub fn evaluate_registration(
    raw: &Path,
    dataset: &Path,
    opts: &RegistrationTruthOptions,
) -> Result<RegistrationAccuracy, RegistrationTruthError> {
    let truth = FlightTruth::open(raw, opts.scene.as_ref())?;
    evaluate_with(&truth, dataset, opts.grid)
}

/// [`evaluate_registration`] with the flight's truth already open (several imports of one flight).
pub fn evaluate_with(
    truth: &FlightTruth,
    dataset: &Path,
    grid: usize,
) -> Result<RegistrationAccuracy, RegistrationTruthError> {
    let mismatch = RegistrationTruthError::Mismatch;
    // The import's own transforms.json: `msnerf process` keeps it as transforms.import.json once SfM has rewritten
    // the poses (and moved the camera model into the frames).
    let transforms_path = match dataset.join("transforms.import.json") {
        p if p.is_file() => p,
        _ => dataset.join("transforms.json"),
    };
    let transforms: serde_json::Value = read_json(&transforms_path)?;
    let reference_band = transforms["reference_band"]
        .as_str()
        .ok_or_else(|| RegistrationTruthError::Format {
            path: transforms_path.clone(),
            reason: "no `reference_band`".into(),
        })?
        .to_string();
    if transforms.get("rig_cameras").is_some() {
        return Err(mismatch(
            "the dataset keeps every band in its own camera (--rig-cameras): nothing registered".into(),
        ));
    }
    let undistorted = transforms["camera_model"].as_str() == Some("PINHOLE");
    let report: Report = read_json(&dataset.join("import_report.json"))?;
    let names: Vec<String> =
        report.frames.first().map_or(Vec::new(), |f| f.registration.iter().map(|r| r.band.clone()).collect());
    let nb = names.len();
    let mut per_capture = Vec::new();
    let mut errors: Vec<Vec<SampleErrors>> = Vec::new();
    let mut skipped = Vec::new();
    let mut crop: Option<[usize; 4]> = None;
    for frame in &report.frames {
        let name = Path::new(&frame.file).file_stem().map_or(frame.capture.clone(), |s| s.to_string_lossy().into());
        let view = match truth.view_of(&frame.capture) {
            Err(_) => {
                skipped.push(SkippedCapture { capture: name, reason: "not a capture of the raw flight".into() });
                continue;
            }
            Ok(None) => {
                skipped.push(SkippedCapture { capture: name, reason: "a calibration-panel capture".into() });
                continue;
            }
            Ok(Some(v)) => v,
        };
        let bands_here: Vec<String> = frame.registration.iter().map(|r| r.band.clone()).collect();
        if bands_here != names {
            return Err(mismatch(format!("{name}: bands {bands_here:?}, the first frame has {names:?}")));
        }
        let target = truth.target(&frame.capture, &reference_band, undistorted)?;
        let (x0, y0) = ((target.cx - frame.cx).round(), (target.cy - frame.cy).round());
        if !(x0 >= 0.0 && y0 >= 0.0 && x0 < 1e9 && y0 < 1e9) {
            return Err(mismatch(format!("{name}: the crop starts at ({x0}, {y0})")));
        }
        let (x0, y0) = (x0 as usize, y0 as usize);
        let c = [x0, y0, x0 + frame.width, y0 + frame.height];
        crop.get_or_insert(c);
        let q = Question { reference_band: &reference_band, undistorted, crop: c, grid };
        let band_errors = frame
            .registration
            .iter()
            .map(|rb| truth.warp_errors(&frame.capture, &rb.band, &rb.warp, &q))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some(b) = band_errors.iter().position(|e| e.errors.is_empty()) {
            return Err(mismatch(format!("{name}, band {}: no sample has a truth", names[b])));
        }
        per_capture.push(CaptureAccuracy {
            capture: name,
            view,
            median_px: band_errors.iter().map(|e| crate::util::stats::median(&e.errors)).collect(),
        });
        errors.push(band_errors);
    }
    let bands = (0..nb)
        .map(|bi| {
            let all = sorted(errors.iter().flat_map(|c| c[bi].errors.iter().copied()).collect());
            let floor =
                sorted(errors.iter().flat_map(|c| c[bi].floor.iter().copied()).filter(|v| v.is_finite()).collect());
            let medians = sorted(per_capture.iter().map(|c| c.median_px[bi]).collect());
            let worst = per_capture.iter().max_by(|a, b| a.median_px[bi].total_cmp(&b.median_px[bi]));
            BandAccuracy {
                band: names[bi].clone(),
                median_px: percentile_sorted(&all, 0.5),
                p95_px: percentile_sorted(&all, 0.95),
                spread_px: percentile_sorted(&medians, 0.95),
                worst_capture_px: worst.map_or(f64::NAN, |c| c.median_px[bi]),
                worst_capture: worst.map_or(String::new(), |c| c.capture.clone()),
                floor_median_px: percentile_sorted(&floor, 0.5),
                floor_p95_px: percentile_sorted(&floor, 0.95),
                samples: all.len(),
            }
        })
        .collect();
    Ok(RegistrationAccuracy {
        scene: truth.scene.clone(),
        sensor: truth.sensor,
        width: truth.width,
        height: truth.height,
        reference_band,
        registration: report.summary.registration,
        undistort: undistorted,
        crop: crop.unwrap_or([0; 4]),
        grid,
        captures: per_capture.len(),
        skipped,
        bands,
        per_capture,
    })
}
