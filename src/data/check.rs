//! `dataset check` as a library function: loads a dataset, decodes every image, and reports frames, splits,
//! bands, image size and sample type, per-band value ranges, scene bounds in world units, the host memory a
//! full load needs and what the cache will use. Every problem is collected, not just the first.

use std::fmt;
use std::path::Path;

use serde::Serialize;

use super::cache::{plan_cache, CachePlan};
use super::error::DataError;
use super::loader::{load_dataset, LoadOptions};
use super::pose::PoseTransform;
use super::raster::SampleType;
use super::split::Split;

/// One band in the report.
#[derive(Debug, Clone, Serialize)]
pub struct BandReport {
    pub name: String,
    pub center_nm: Option<f64>,
    pub fwhm_nm: Option<f64>,
    /// Range of the values the model will see (after black level and scaling), over all readable images.
    pub min: Option<f32>,
    pub max: Option<f32>,
}

/// Radiometry and registration facts that `msnerf import rig` writes into `transforms.json` (docs/dataset.md).
#[derive(Debug, Clone, Serialize)]
pub struct ImportInfo {
    /// `reflectance` or `radiance`.
    pub units: String,
    /// Per band: name, radiance units, irradiance source (`panel`, `dls`, `none`) and the panel irradiance.
    pub calibration: Vec<(String, String, String, Option<f64>)>,
    pub reference_band: Option<String>,
    /// Per band, the largest registration residual over the frames (pixels; `None` for the reference band or
    /// when the import did not measure it).
    pub max_residual_px: Vec<Option<f64>>,
    /// `pose_prior.source` when the poses are priors (GPS) rather than SfM poses.
    pub pose_prior: Option<String>,
}

fn import_info(root: &serde_json::Value) -> Option<ImportInfo> {
    let units = root.get("units")?.as_str()?.to_string();
    let calibration: Vec<_> = root
        .get("calibration")
        .and_then(|c| c.as_array())
        .map(|a| {
            a.iter()
                .map(|c| {
                    let s = |k: &str| c.get(k).and_then(|v| v.as_str()).unwrap_or("-").to_string();
                    (s("band"), s("radiance"), s("source"), c.get("irradiance").and_then(|v| v.as_f64()))
                })
                .collect()
        })
        .unwrap_or_default();
    let mut max_residual_px: Vec<Option<f64>> = vec![None; calibration.len()];
    for f in root.get("frames").and_then(|f| f.as_array()).into_iter().flatten() {
        for (b, r) in f.get("registration_residual_px").and_then(|r| r.as_array()).into_iter().flatten().enumerate() {
            if let (Some(v), Some(slot)) = (r.as_f64(), max_residual_px.get_mut(b)) {
                *slot = Some(slot.map_or(v, |m: f64| m.max(v)));
            }
        }
    }
    Some(ImportInfo {
        units,
        calibration,
        reference_band: root.get("reference_band").and_then(|v| v.as_str()).map(str::to_string),
        max_residual_px,
        pose_prior: root.get("pose_prior").and_then(|p| p.get("source")).and_then(|v| v.as_str()).map(str::to_string),
    })
}

/// What `msnerf dataset check DIR` prints (Display) or writes (`to_json`).
#[derive(Debug, Serialize)]
pub struct CheckReport {
    pub dir: String,
    pub frames: usize,
    pub train: usize,
    pub eval: usize,
    pub test: usize,
    pub unused: usize,
    pub split_method: Option<String>,
    pub width: u32,
    pub height: u32,
    pub sample_type: Option<SampleType>,
    pub bands: Vec<BandReport>,
    /// Camera centres' bounding box in the dataset's world units: (min, max).
    pub scene_bounds: Option<([f64; 3], [f64; 3])>,
    pub pose_transform: Option<PoseTransform>,
    /// Host bytes to hold every image (all splits) in its stored type, masks included.
    pub full_load_bytes: u64,
    pub cache_budget_bytes: u64,
    /// The cache plan for the train split under the budget.
    pub cache: Option<CachePlan>,
    /// Frames left out for an outlying camera centre (with `--drop-outliers`).
    pub dropped_outliers: Vec<String>,
    /// Whether nerfstudio's `applied_transform` was undone (poses in COLMAP's frame).
    pub applied_transform_undone: bool,
    /// `crs` of the world frame, described (`EPSG:32650 (WGS 84 / UTM zone 50N)`), when the dataset has one.
    pub crs: Option<String>,
    /// What an import from raw rig files recorded (units, calibration, registration), when it did.
    pub import: Option<ImportInfo>,
    /// With `rig_cameras`: per band, its camera's distance from the frame camera (world units) and its rotation
    /// from it (degrees).
    pub rig_cameras: Option<Vec<(String, f64, f64)>>,
    /// Named concerns that do not stop training (registration residuals above a pixel, GPS pose priors).
    pub warnings: Vec<String>,
    /// Every problem found, one line each.
    pub errors: Vec<String>,
    #[serde(skip)]
    pub problems: Vec<DataError>,
}

impl CheckReport {
    pub fn is_ok(&self) -> bool {
        self.problems.is_empty()
    }
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("report is plain data")
    }
    fn push(&mut self, e: DataError) {
        for e in e.flatten() {
            self.errors.push(e.to_string());
            self.problems.push(e);
        }
    }
}

/// Checks the dataset at `dir` (its folder or its transforms.json) against a host cache budget.
pub fn check_dataset(dir: &Path, budget_bytes: u64) -> CheckReport {
    check_dataset_with(dir, budget_bytes, &LoadOptions::default())
}

/// [`check_dataset`] with load options (`drop_outliers`).
pub fn check_dataset_with(dir: &Path, budget_bytes: u64, options: &LoadOptions) -> CheckReport {
    let mut rep = CheckReport {
        dir: dir.display().to_string(),
        frames: 0,
        train: 0,
        eval: 0,
        test: 0,
        unused: 0,
        split_method: None,
        width: 0,
        height: 0,
        sample_type: None,
        bands: vec![],
        scene_bounds: None,
        pose_transform: None,
        full_load_bytes: 0,
        cache_budget_bytes: budget_bytes,
        cache: None,
        import: None,
        rig_cameras: None,
        dropped_outliers: vec![],
        applied_transform_undone: false,
        crs: None,
        warnings: vec![],
        errors: vec![],
        problems: vec![],
    };
    let ds = match load_dataset(dir, options) {
        Ok(ds) => ds,
        Err(e) => {
            rep.push(e);
            return rep;
        }
    };
    if let Ok(root) = super::transforms::read_json::<serde_json::Value>(&ds.transforms_path, "transforms.json") {
        rep.import = import_info(&root);
    }
    rep.rig_cameras = ds.rig.as_ref().map(|_| {
        (0..ds.n_bands())
            .map(|b| {
                let m = ds.band_camera(b).expect("the dataset has a rig").rig_from_band;
                let offset = (0..3).map(|i| m[i][3] * m[i][3]).sum::<f64>().sqrt();
                let trace = m[0][0] + m[1][1] + m[2][2];
                let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
                (ds.bands[b].name.clone(), offset, angle)
            })
            .collect()
    });
    rep.dropped_outliers = ds.dropped_outliers.clone();
    rep.applied_transform_undone = ds.applied_transform_undone.is_some();
    rep.crs = ds.crs.as_ref().map(|c| c.describe());
    rep.frames = ds.frames.len();
    let count = |s: Split| ds.frames.iter().filter(|f| f.split == s).count();
    rep.train = count(Split::Train);
    rep.eval = count(Split::Eval);
    rep.test = count(Split::Test);
    rep.unused = count(Split::Unused);
    rep.split_method = Some(format!("{:?}", ds.split_method));
    rep.width = ds.width;
    rep.height = ds.height;
    rep.sample_type = Some(ds.sample_type);
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for f in &ds.frames {
        for i in 0..3 {
            lo[i] = lo[i].min(f.c2w[i][3]);
            hi[i] = hi[i].max(f.c2w[i][3]);
        }
    }
    rep.scene_bounds = Some((lo, hi));
    rep.pose_transform = Some(ds.pose_transform());
    rep.full_load_bytes = (0..ds.frames.len()).map(|i| ds.frame_bytes(i)).sum();
    let train = ds.split_indices(Split::Train);
    let per = train.iter().map(|&i| ds.frame_bytes(i)).max().unwrap_or(0);
    rep.cache = plan_cache(train.len(), per, budget_bytes);
    if rep.cache.is_none() && !train.is_empty() {
        rep.push(DataError::InvalidValue {
            path: ds.transforms_path.clone(),
            key: "cache budget".into(),
            frame: None,
            reason: format!("{budget_bytes} bytes cannot hold one image of {per} bytes plus scratch"),
        });
    }
    let mut ranges: Vec<Option<(f32, f32)>> = vec![None; ds.n_bands()];
    // Per frame and band, the median and 99th percentile of a strided sample of unmasked pixels.
    let mut quantiles: Vec<Vec<[f32; 2]>> = vec![Vec::new(); ds.n_bands()];
    for i in 0..ds.frames.len() {
        match ds.read_frame(i) {
            Ok(r) => {
                for (b, q) in quantiles.iter_mut().enumerate() {
                    let (w, h) = (ds.width, ds.height);
                    let sample = (0..w * h)
                        .step_by(7)
                        .map(|p| (p / w, p % w))
                        .filter(|&(row, col)| r.mask_at(row, col) > 0)
                        .map(|(row, col)| r.get(row, col, b));
                    q.push(crate::rig::flight_checks::quantiles(sample));
                }
                for (b, rr) in r.band_ranges().into_iter().enumerate() {
                    if let Some((l, h)) = rr {
                        ranges[b] = Some(match ranges[b] {
                            None => (l, h),
                            Some((a, c)) => (a.min(l), c.max(h)),
                        });
                    }
                }
            }
            Err(e) => rep.push(e),
        }
        if let Err(e) = ds.read_depth(i) {
            rep.push(e);
        }
    }
    flight_checks(&mut rep, &ds, &quantiles);
    rep.bands = ds
        .bands
        .iter()
        .zip(ranges)
        .map(|(b, r)| BandReport {
            name: b.name.clone(),
            center_nm: b.center_nm,
            fwhm_nm: b.fwhm_nm,
            min: r.map(|r| r.0),
            max: r.map(|r| r.1),
        })
        .collect();
    rep
}

/// Checks over the whole flight: reflectance that is implausible for its units (a problem), cameras that all
/// sit at one point (a problem: the dataset is not posed), registration residuals above a pixel (warnings).
fn flight_checks(rep: &mut CheckReport, ds: &super::loader::Dataset, quantiles: &[Vec<[f32; 2]>]) {
    use crate::rig::flight_checks::{flight_quantiles, reflectance_problem, RESIDUAL_LIMIT_PX};
    let problem = |key: &str, reason: String| DataError::InvalidValue {
        path: ds.transforms_path.clone(),
        key: key.into(),
        frame: None,
        reason,
    };
    if rep.import.as_ref().is_some_and(|im| im.units == "reflectance") {
        for (b, q) in ds.bands.iter().zip(quantiles) {
            if let Some(msg) = flight_quantiles(q).and_then(|(m, p)| reflectance_problem(&b.name, m, p)) {
                rep.push(problem("units", msg));
            }
        }
    }
    if ds.frames.len() > 1 {
        let c0 = ds.frames[0].c2w;
        let spread = ds
            .frames
            .iter()
            .map(|f| (0..3).map(|i| (f.c2w[i][3] - c0[i][3]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        if spread == 0.0 {
            rep.push(problem(
                "frames[].transform_matrix",
                format!(
                    "all {} cameras sit at one point: the dataset is not posed (no GPS in the files?); run `msnerf \
                     sfm` or `msnerf import poses`",
                    ds.frames.len()
                ),
            ));
        }
    }
    if let Some(im) = &rep.import {
        let bands: Vec<String> = im.calibration.iter().map(|c| c.0.clone()).collect();
        for (band, r) in bands.iter().zip(&im.max_residual_px) {
            if let Some(r) = r.filter(|r| *r > RESIDUAL_LIMIT_PX) {
                rep.warnings.push(format!(
                    "band {band}: registration residual up to {r:.2} px (above {RESIDUAL_LIMIT_PX} px: not aligned with \
                     the reference everywhere)"
                ));
            }
        }
    }
}

fn gib(b: u64) -> String {
    format!("{:.2} GiB", b as f64 / (1u64 << 30) as f64)
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "dataset {}", self.dir)?;
        writeln!(
            f,
            "  frames {} (train {}, eval {}, test {}, unused {}; split by {})",
            self.frames,
            self.train,
            self.eval,
            self.test,
            self.unused,
            self.split_method.as_deref().unwrap_or("-")
        )?;
        match &self.crs {
            Some(c) => writeln!(f, "  crs {c}: outputs with coordinates carry it")?,
            None if self.frames > 0 => writeln!(f, "  crs: none (a local frame; outputs carry no CRS)")?,
            None => {}
        }
        if self.applied_transform_undone {
            writeln!(f, "  poses: nerfstudio's applied_transform undone (outputs in COLMAP's frame)")?;
        }
        for n in &self.dropped_outliers {
            writeln!(f, "  left out: {n} (camera centre far outside the others)")?;
        }
        if let Some(t) = self.sample_type {
            writeln!(f, "  images {}x{} {:?}", self.width, self.height, t)?;
        }
        for b in &self.bands {
            let nm = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v}"));
            let r = match (b.min, b.max) {
                (Some(l), Some(h)) => format!("[{l}, {h}]"),
                _ => "-".into(),
            };
            writeln!(f, "  band {:<10} centre {} nm  fwhm {} nm  values {r}", b.name, nm(b.center_nm), nm(b.fwhm_nm))?;
        }
        if let Some(im) = &self.import {
            writeln!(f, "  units {} (imported from raw rig files)", im.units)?;
            for (i, (band, rad, source, e)) in im.calibration.iter().enumerate() {
                let e = e.map_or(String::new(), |e| format!(", panel irradiance {e:.5}"));
                let r = match im.max_residual_px.get(i).copied().flatten() {
                    Some(v) => format!(", registration residual up to {v:.3} px"),
                    None if im.reference_band.as_deref() == Some(band.as_str()) => ", registration reference".into(),
                    None => String::new(),
                };
                writeln!(f, "    {band}: radiance in {rad}, irradiance from {source}{e}{r}")?;
            }
            if let Some(p) = &im.pose_prior {
                writeln!(f, "  poses are {p} priors: import SfM poses before training a real flight")?;
            }
        }
        if let Some(rig) = &self.rig_cameras {
            writeln!(f, "  rig cameras: every band traced from its own camera (rig-aware training)")?;
            for (band, offset, angle) in rig {
                writeln!(f, "    {band}: {offset:.4} world units from the frame camera, turned {angle:.3} deg")?;
            }
        }
        if let Some((lo, hi)) = self.scene_bounds {
            writeln!(f, "  camera centres (world units) min {lo:?} max {hi:?}")?;
        }
        writeln!(f, "  full load {}", gib(self.full_load_bytes))?;
        match &self.cache {
            Some(c) => writeln!(
                f,
                "  cache budget {}: {} of {} train images resident, peak {}{}",
                gib(self.cache_budget_bytes),
                c.n_resident,
                c.n_images,
                gib(c.peak_bytes),
                if c.fits_all { " (all fit)" } else { " (resampled)" }
            )?,
            None => writeln!(f, "  cache budget {}: no plan", gib(self.cache_budget_bytes))?,
        }
        for w in &self.warnings {
            writeln!(f, "  warning: {w}")?;
        }
        if self.errors.is_empty() {
            writeln!(f, "  OK{}", if self.warnings.is_empty() { "" } else { " (with the warnings above)" })
        } else {
            writeln!(f, "  {} problem(s):", self.errors.len())?;
            for e in &self.errors {
                writeln!(f, "    - {e}")?;
            }
            Ok(())
        }
    }
}
