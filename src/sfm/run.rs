//! The `msnerf sfm` pipeline (module doc of [`super`]): reads the dataset's frames, writes COLMAP's images, runs
//! COLMAP, reads the largest model back, geo-registers it to GPS, and writes poses into the dataset.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use super::colmap::Colmap;
use super::georef::{self, GeoFit};
use super::images::{self, BandChoice, FrameImages};
use super::SfmError;
use crate::geo::{Crs, Projector};
use crate::poses::apply::stem;
use crate::poses::colmap::{read_model, to_pose_model, ColmapModel};

/// Feature matching strategy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Matcher {
    /// Exhaustive up to 50 frames; above, spatial when the frames have GPS or pose priors, else sequential.
    Auto,
    /// Every pair (n (n - 1) / 2 pairs).
    Exhaustive,
    /// Each frame with the next `overlap` in file-name order (capture order for a flight).
    Sequential,
    /// Each frame with its `overlap` nearest frames by GPS / prior position (a pair list for COLMAP's
    /// `matches_importer`; COLMAP 3.8's own `spatial_matcher` reads EXIF GPS, which the PNGs do not carry).
    Spatial,
}

/// Features per image for `max_features: None`: one per 150 pixels of the (upsampled) image, between 1024 and
/// COLMAP's default of 8192: enough for a pose on small images without paying 8192^2 per pair on a CPU.
pub fn auto_max_features(pixels: u64) -> usize {
    ((pixels / 150) as usize).clamp(1024, 8192)
}

/// Frames up to which `auto` matches every pair (COLMAP's CPU matching of 100 frames, 4950 pairs, takes over
/// 6 minutes on 2 cores).
pub const EXHAUSTIVE_UP_TO: usize = 50;

/// Pairs (i < j) of each frame with its `k` nearest others by `pos` (None: no position; such a frame is only
/// matched when it is another's neighbour).
fn spatial_pairs(pos: &[Option<[f64; 3]>], k: usize) -> Vec<(usize, usize)> {
    let mut pairs = std::collections::BTreeSet::new();
    for (i, p) in pos.iter().enumerate() {
        let Some(p) = p else { continue };
        let mut d: Vec<(f64, usize)> = pos
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .filter_map(|(j, q)| q.map(|q| ((0..3).map(|c| (p[c] - q[c]).powi(2)).sum::<f64>(), j)))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0));
        for &(_, j) in d.iter().take(k) {
            pairs.insert((i.min(j), i.max(j)));
        }
    }
    pairs.into_iter().collect()
}

/// What `msnerf sfm` is asked to do.
#[derive(Debug, Clone)]
pub struct SfmOptions {
    pub dataset: PathBuf,
    pub colmap: Option<PathBuf>,
    pub band: BandChoice,
    /// None: [`images::auto_upsample`].
    pub upsample: Option<u32>,
    pub matcher: Matcher,
    /// Sequential: each frame with the next `overlap`; spatial: with its `overlap` nearest.
    pub overlap: usize,
    /// SIFT's peak threshold (COLMAP's default 0.0067 is tuned for large photographs).
    pub peak_threshold: f64,
    /// Most SIFT features kept per image (None: [`auto_max_features`] of the image size). CPU matching time grows
    /// with the square of it.
    pub max_features: Option<usize>,
    /// Let bundle adjustment refine focal length, principal point and distortion (they are kept fixed when the
    /// dataset states them and all frames share them).
    pub refine_intrinsics: bool,
    /// Projected CRS for geo-registration (default: the dataset's `crs`, else the first GPS fix's UTM zone).
    pub crs: Option<Crs>,
    /// Leave the model in COLMAP's frame even when the frames have GPS.
    pub no_georef: bool,
    /// GPS noise floor for the robust fit (metres); also the fixes' standard deviation in the bundle adjustment.
    pub gps_error_m: f64,
    /// With ground control, keep the similarity fit alone (no bundle adjustment on the control points).
    pub no_adjust: bool,
    pub threads: usize,
}

/// Frames matched with each frame (sequential or spatial matching).
pub const DEFAULT_OVERLAP: usize = 20;
/// SIFT's peak threshold.
pub const DEFAULT_PEAK_THRESHOLD: f64 = 0.002;
/// GPS noise floor for the robust fit, and the fixes' standard deviation in the bundle adjustment (metres).
pub const DEFAULT_GPS_ERROR_M: f64 = 1.0;

impl SfmOptions {
    pub fn new(dataset: &Path) -> SfmOptions {
        SfmOptions {
            dataset: dataset.to_path_buf(),
            colmap: None,
            band: BandChoice::Auto,
            upsample: None,
            matcher: Matcher::Auto,
            overlap: DEFAULT_OVERLAP,
            peak_threshold: DEFAULT_PEAK_THRESHOLD,
            max_features: None,
            refine_intrinsics: false,
            crs: None,
            no_georef: false,
            gps_error_m: DEFAULT_GPS_ERROR_M,
            no_adjust: false,
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
        }
    }
}

/// What `msnerf sfm` did (also written as `colmap/sfm_report.json`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct SfmReport {
    pub colmap: String,
    pub workspace: PathBuf,
    pub band: String,
    pub upsample: u32,
    pub matcher: Matcher,
    pub intrinsics: String,
    pub frames: usize,
    pub registered: usize,
    /// Frames COLMAP did not register (moved to `unregistered_frames`, marked unused).
    pub unregistered: Vec<String>,
    pub points: usize,
    pub mean_reprojection_error_px: Option<f64>,
    pub mean_track_length: Option<f64>,
    /// Models COLMAP made (the largest is used).
    pub models: Vec<usize>,
    pub georef: Option<GeoFit>,
    pub crs: Option<String>,
    pub seconds: HashMap<String, f64>,
    pub backup: Option<PathBuf>,
}

/// One frame as `sfm` needs it.
struct SfmFrame {
    images: FrameImages,
    camera: Vec<(String, Value)>,
    gps: Option<[f64; 3]>,
    prior: Option<[f64; 3]>,
}

const CAMERA_KEYS: [&str; 13] =
    ["camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2"];

fn dataset_err(path: &Path, reason: impl Into<String>) -> SfmError {
    SfmError::Dataset { path: path.to_path_buf(), reason: reason.into() }
}

fn frames_of(root: &Value, tpath: &Path) -> Result<Vec<SfmFrame>, SfmError> {
    let dir = tpath.parent().unwrap_or(Path::new("."));
    let top = root.as_object().ok_or_else(|| dataset_err(tpath, "top level is not an object"))?;
    // GPS pose priors (an import without GPS writes every camera at the origin and says so with a null origin).
    let has_prior = top.contains_key("pose_prior")
        && top.contains_key("crs")
        && !matches!(top.get("pose_prior").and_then(|p| p.get("origin")), Some(Value::Null));
    let mut all: Vec<&Value> = Vec::new();
    for key in ["frames", "unregistered_frames"] {
        if let Some(v) = top.get(key) {
            all.extend(v.as_array().ok_or_else(|| dataset_err(tpath, format!("`{key}` is not a list")))?);
        }
    }
    if all.is_empty() {
        return Err(dataset_err(tpath, "no frames"));
    }
    let mut out = Vec::with_capacity(all.len());
    for (i, f) in all.iter().enumerate() {
        let files: Vec<String> = match (f.get("file_path").and_then(|v| v.as_str()), f.get("band_files")) {
            (Some(p), _) => vec![p.to_string()],
            (None, Some(Value::Array(b))) => b.iter().filter_map(|v| v.as_str().map(str::to_string)).collect(),
            _ => return Err(dataset_err(tpath, format!("frame {i}: neither `file_path` nor `band_files`"))),
        };
        let name = files[0].clone();
        let paths: Vec<PathBuf> = files.iter().map(|p| dir.join(p)).collect();
        if let Some(missing) = paths.iter().find(|p| !p.is_file()) {
            return Err(dataset_err(tpath, format!("frame {name}: image {} does not exist", missing.display())));
        }
        let camera = CAMERA_KEYS
            .iter()
            .filter_map(|k| f.get(*k).or_else(|| top.get(*k)).map(|v| (k.to_string(), v.clone())))
            .collect();
        let gps = f.get("gps").and_then(|g| {
            Some([
                g.get("latitude")?.as_f64()?,
                g.get("longitude")?.as_f64()?,
                g.get("altitude").and_then(|a| a.as_f64()).unwrap_or(0.0),
            ])
        });
        let prior = if has_prior {
            f.get("transform_matrix").and_then(|m| Some([m[0][3].as_f64()?, m[1][3].as_f64()?, m[2][3].as_f64()?]))
        } else {
            None
        };
        out.push(SfmFrame { images: FrameImages { name, files: paths }, camera, gps, prior });
    }
    Ok(out)
}

/// COLMAP's camera model and parameters for the dataset's shared intrinsics, scaled by `factor`; None when the
/// frames do not share one camera or do not state it.
fn colmap_camera(frames: &[SfmFrame], factor: f64) -> Option<(String, Vec<f64>)> {
    let first = &frames[0].camera;
    if frames.iter().any(|f| &f.camera != first) {
        return None;
    }
    let get = |k: &str| first.iter().find(|(n, _)| n == k).and_then(|(_, v)| v.as_f64());
    let (fx, fy, cx, cy) = (get("fl_x")?, get("fl_y").or(get("fl_x"))?, get("cx")?, get("cy")?);
    let model = first.iter().find(|(n, _)| n == "camera_model").and_then(|(_, v)| v.as_str()).unwrap_or("OPENCV");
    let d = |k: &str| get(k).unwrap_or(0.0);
    let base = vec![fx * factor, fy * factor, cx * factor, cy * factor];
    match model {
        "OPENCV" if d("k1") == 0.0 && d("k2") == 0.0 && d("k3") == 0.0 && d("p1") == 0.0 && d("p2") == 0.0 => {
            Some(("PINHOLE".into(), base))
        }
        "PINHOLE" => Some(("PINHOLE".into(), base)),
        "OPENCV" if d("k3") == 0.0 => {
            Some(("OPENCV".into(), [base, vec![d("k1"), d("k2"), d("p1"), d("p2")]].concat()))
        }
        "OPENCV" => Some((
            "FULL_OPENCV".into(),
            [base, vec![d("k1"), d("k2"), d("p1"), d("p2"), d("k3"), 0.0, 0.0, 0.0]].concat(),
        )),
        "OPENCV_FISHEYE" => Some(("OPENCV_FISHEYE".into(), [base, vec![d("k1"), d("k2"), d("k3"), d("k4")]].concat())),
        _ => None,
    }
}

/// Divides a COLMAP model's cameras back to the dataset's pixels (focal lengths, principal point, size, and the
/// points' reprojection errors).
fn unscale(m: &mut ColmapModel, factor: u32) {
    if factor == 1 {
        return;
    }
    let f = f64::from(factor);
    for c in m.cameras.values_mut() {
        let n = match c.model.as_str() {
            "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" | "SIMPLE_RADIAL_FISHEYE" | "RADIAL_FISHEYE" | "FOV" => 3,
            _ => 4,
        };
        c.params.iter_mut().take(n).for_each(|p| *p /= f);
        c.width /= u64::from(factor);
        c.height /= u64::from(factor);
    }
    // Reprojection errors and the 2-D points in the dataset's pixels too.
    for p in &mut m.points {
        p.error /= f;
    }
    for im in &mut m.images {
        im.points2d.iter_mut().for_each(|p| *p = [p[0] / f, p[1] / f]);
    }
}

/// With `rig_cameras`: the bands (indices into `names`) whose camera is the frame camera (identity `rig_from_band`).
fn frame_camera_bands(root: &serde_json::Value, names: &[String]) -> Option<Vec<usize>> {
    let cams = root.get("rig_cameras")?.get("cameras")?.as_array()?;
    let identity = |m: &serde_json::Value| {
        (0..3).all(|i| {
            (0..4).all(|j| {
                let v = m.get(i).and_then(|r| r.get(j)).and_then(|v| v.as_f64());
                v.is_some_and(|v| (v - f64::from(u8::from(i == j))).abs() < 1e-9)
            })
        })
    };
    Some(
        cams.iter()
            .filter(|c| c.get("rig_from_band").is_some_and(identity))
            .filter_map(|c| c.get("band")?.as_str())
            .filter_map(|n| names.iter().position(|m| m.eq_ignore_ascii_case(n)))
            .collect(),
    )
}

/// Runs the whole pipeline.
pub fn run_sfm(o: &SfmOptions) -> Result<SfmReport, SfmError> {
    let t_all = std::time::Instant::now();
    let colmap = Colmap::find(o.colmap.as_deref())?;
    let tpath = crate::poses::transforms_path(&o.dataset);
    let root = crate::poses::read_transforms(&tpath)?;
    let frames = frames_of(&root, &tpath)?;
    let stems: Vec<String> = frames.iter().map(|f| stem(&f.images.name)).collect();
    let mut seen: HashMap<&str, &str> = HashMap::new();
    for (s, f) in stems.iter().zip(&frames) {
        if let Some(prev) = seen.insert(s, &f.images.name) {
            return Err(dataset_err(&tpath, format!("frames {prev} and {} share the file stem `{s}`", f.images.name)));
        }
    }
    // Band names (or indices) and the band COLMAP sees.
    let names: Vec<String> = match root.get("bands").and_then(|b| b.as_array()) {
        Some(b) => b
            .iter()
            .enumerate()
            .map(|(i, v)| v.get("name").and_then(|n| n.as_str()).map_or(i.to_string(), str::to_string))
            .collect(),
        None => (0..images::band_count(&frames[0].images)?).map(|i| i.to_string()).collect(),
    };
    let frame_images: Vec<FrameImages> = frames.iter().map(|f| f.images.clone()).collect();
    let band = match frame_camera_bands(&root, &names) {
        // `rig_cameras`: the frames' poses are the frame camera's, so COLMAP must see a band seen through it.
        Some(ok) => {
            let pick = match &o.band {
                images::BandChoice::Pan => None,
                images::BandChoice::Auto => ok.first().copied(),
                named => images::choose_band(&frame_images, &names, named)?.filter(|b| ok.contains(b)),
            };
            Some(pick.ok_or_else(|| {
                let list: Vec<&str> = ok.iter().map(|&b| names[b].as_str()).collect();
                dataset_err(
                    &tpath,
                    format!(
                        "rig_cameras: COLMAP must see a band whose camera is the frame camera (identity rig_from_band): \
                         {}; give --band with one of them",
                        if list.is_empty() { "none has one".to_string() } else { list.join(", ") }
                    ),
                )
            })?)
        }
        None => images::choose_band(&frame_images, &names, &o.band)?,
    };
    let band_desc = band.map_or("pan (mean of all bands)".to_string(), |b| names[b].clone());
    let (w, h) = {
        let c = &frames[0].camera;
        let get = |k: &str| c.iter().find(|(n, _)| n == k).and_then(|(_, v)| v.as_u64());
        match (get("w"), get("h")) {
            (Some(w), Some(h)) => (w, h),
            _ => images::size_of(&frames[0].images)?,
        }
    };
    let factor = match o.upsample {
        Some(0) => return Err(SfmError::Option { key: "--upsample".into(), reason: "must be 1 or more".into() }),
        Some(f) => f,
        None => images::auto_upsample(w, h),
    };

    // The workspace: DATASET/colmap (COLMAP's database, images, models and every step's log).
    let ws = tpath.parent().unwrap_or(Path::new(".")).join("colmap");
    for sub in ["images", "sparse"] {
        let p = ws.join(sub);
        if p.exists() {
            std::fs::remove_dir_all(&p).map_err(|e| dataset_err(&p, e.to_string()))?;
        }
    }
    let db = ws.join("database.db");
    if db.exists() {
        std::fs::remove_file(&db).map_err(|e| dataset_err(&db, e.to_string()))?;
    }
    std::fs::create_dir_all(ws.join("sparse")).map_err(|e| dataset_err(&ws, e.to_string()))?;
    let t0 = std::time::Instant::now();
    images::write_images(&frame_images, &stems, band, factor, &ws.join("images"))?;
    let mut seconds = HashMap::new();
    seconds.insert("images".to_string(), t0.elapsed().as_secs_f64());

    let s = |v: &Path| v.display().to_string();
    let threads = o.threads.max(1).to_string();
    let camera = colmap_camera(&frames, f64::from(factor));
    let mut fe = vec![
        "--database_path".into(),
        s(&db),
        "--image_path".into(),
        s(&ws.join("images")),
        "--SiftExtraction.use_gpu".into(),
        "0".into(),
        "--SiftExtraction.num_threads".into(),
        threads.clone(),
        "--SiftExtraction.peak_threshold".into(),
        format!("{}", o.peak_threshold),
        "--SiftExtraction.max_image_size".into(),
        format!("{}", (w.max(h) * u64::from(factor)).max(3200)),
        "--SiftExtraction.max_num_features".into(),
        o.max_features.unwrap_or_else(|| auto_max_features(w * h * u64::from(factor * factor))).to_string(),
    ];
    let intrinsics = match &camera {
        Some((model, params)) => {
            fe.extend([
                "--ImageReader.single_camera".into(),
                "1".into(),
                "--ImageReader.camera_model".into(),
                model.clone(),
                "--ImageReader.camera_params".into(),
                params.iter().map(|p| format!("{p}")).collect::<Vec<_>>().join(","),
            ]);
            format!("{model} from the dataset ({})", if o.refine_intrinsics { "refined" } else { "fixed" })
        }
        None => {
            fe.extend(["--ImageReader.camera_model".into(), "OPENCV".into()]);
            "OPENCV per image, estimated by COLMAP (the frames state no shared camera)".to_string()
        }
    };
    seconds.insert("features".into(), colmap.step(&ws, "feature_extractor", &fe)?);
    // Positions for spatial matching: GPS fixes (degrees scaled to rough metres) or pose priors.
    let positions: Vec<Option<[f64; 3]>> = frames
        .iter()
        .map(|f| f.prior.or(f.gps.map(|g| [g[1] * 111_320.0 * g[0].to_radians().cos(), g[0] * 110_540.0, g[2]])))
        .collect();
    let with_position = positions.iter().filter(|p| p.is_some()).count();
    let matcher = match o.matcher {
        Matcher::Auto if frames.len() <= EXHAUSTIVE_UP_TO => Matcher::Exhaustive,
        Matcher::Auto if with_position * 10 >= frames.len() * 9 => Matcher::Spatial,
        Matcher::Auto => Matcher::Sequential,
        Matcher::Spatial if with_position < 2 => {
            return Err(SfmError::Option {
                key: "--matcher spatial".into(),
                reason: "the frames carry no GPS fixes or pose priors to find neighbours by".into(),
            })
        }
        m => m,
    };
    let mut mt = vec![
        "--database_path".into(),
        s(&db),
        "--SiftMatching.use_gpu".into(),
        "0".into(),
        "--SiftMatching.num_threads".into(),
        threads.clone(),
    ];
    let step = match matcher {
        Matcher::Sequential => {
            mt.extend([
                "--SequentialMatching.overlap".into(),
                o.overlap.to_string(),
                "--SequentialMatching.loop_detection".into(),
                "0".into(),
            ]);
            "sequential_matcher"
        }
        Matcher::Spatial => {
            let pairs = spatial_pairs(&positions, o.overlap);
            let text: String = pairs.iter().map(|&(i, j)| format!("{}.png {}.png\n", stems[i], stems[j])).collect();
            let list = ws.join("pairs.txt");
            std::fs::write(&list, text).map_err(|e| dataset_err(&list, e.to_string()))?;
            mt.extend(["--match_list_path".into(), s(&list), "--match_type".into(), "pairs".into()]);
            "matches_importer"
        }
        _ => "exhaustive_matcher",
    };
    seconds.insert("matching".into(), colmap.step(&ws, step, &mt)?);
    let fixed = camera.is_some() && !o.refine_intrinsics;
    let flag = if fixed { "0" } else { "1" };
    let mp = vec![
        "--database_path".into(),
        s(&db),
        "--image_path".into(),
        s(&ws.join("images")),
        "--output_path".into(),
        s(&ws.join("sparse")),
        "--Mapper.num_threads".into(),
        threads,
        "--Mapper.ba_refine_focal_length".into(),
        flag.into(),
        "--Mapper.ba_refine_principal_point".into(),
        "0".into(),
        "--Mapper.ba_refine_extra_params".into(),
        flag.into(),
    ];
    seconds.insert("mapping".into(), colmap.step(&ws, "mapper", &mp)?);

    // The largest model.
    let mut models = Vec::new();
    let mut best: Option<(usize, PathBuf, ColmapModel)> = None;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(ws.join("sparse"))
        .map_err(|e| dataset_err(&ws.join("sparse"), e.to_string()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for d in dirs {
        let m = read_model(&d)?;
        models.push(m.images.len());
        if best.as_ref().is_none_or(|b| m.images.len() > b.0) {
            best = Some((m.images.len(), d, m));
        }
    }
    let Some((_, model_dir, mut cm)) = best else {
        return Err(SfmError::Step {
            step: "mapper".into(),
            reason: format!(
                "no model: COLMAP could not initialise from the {} frames (too little texture or overlap; try \
                 --band, a larger --upsample or a lower --peak-threshold)",
                frames.len()
            ),
            log: ws.join("mapper.log"),
        });
    };
    unscale(&mut cm, factor);
    let mut model = to_pose_model(&cm, &model_dir)?;

    // Geo-registration to GPS fixes (projected) or GPS pose priors already in the dataset's CRS.
    let mut georef_fit = None;
    let dataset_crs = root
        .get("crs")
        .and_then(|c| c.as_str())
        .map(Crs::parse)
        .transpose()
        .map_err(|e| dataset_err(&tpath, format!("crs: {e}")))?;
    let by_stem: HashMap<&str, usize> = stems.iter().enumerate().map(|(i, s)| (s.as_str(), i)).collect();
    let has_gps = frames.iter().any(|f| f.gps.is_some() || f.prior.is_some());
    let control = super::control::read_ground_control(&root).map_err(|e| dataset_err(&tpath, e))?;
    if (has_gps || control.is_some()) && !o.no_georef {
        let first_fix = frames.iter().find_map(|f| f.gps);
        let control_crs = control
            .as_ref()
            .map(|c| Crs::parse(&c.crs))
            .transpose()
            .map_err(|e| dataset_err(&tpath, format!("ground_control.crs: {e}")))?;
        let crs = match (&o.crs, &dataset_crs, &control_crs, first_fix) {
            (Some(c), _, _, _) => c.clone(),
            (None, Some(c), _, _) => c.clone(),
            (None, None, Some(c), _) => c.clone(),
            (None, None, None, Some(g)) => {
                Crs::utm_for(g[0], g[1]).map_err(|e| dataset_err(&tpath, format!("GPS: {e}")))?
            }
            (None, None, None, None) => {
                return Err(dataset_err(&tpath, "pose priors without a `crs` cannot be geo-registered"))
            }
        };
        if let Some(c) = control_crs.as_ref().filter(|c| c.key() != crs.key()) {
            return Err(SfmError::Option {
                key: "--crs".into(),
                reason: format!(
                    "{} differs from the ground control's {} in {}: import the flight again with this --crs",
                    crs.describe(),
                    c.describe(),
                    tpath.display()
                ),
            });
        }
        let proj = Projector::new(&crs).map_err(|e| SfmError::Option { key: "--crs".into(), reason: e.to_string() })?;
        let (mut names, mut src, mut dst) = (Vec::new(), Vec::new(), Vec::new());
        for im in &model.images {
            let Some(&fi) = by_stem.get(stem(&im.name).as_str()) else { continue };
            let f = &frames[fi];
            let target = match (f.gps, f.prior) {
                (Some(g), _) => proj
                    .from_geodetic(g[0], g[1], g[2])
                    .map_err(|e| dataset_err(&tpath, format!("frame {}: GPS: {e}", f.images.name)))?,
                (None, Some(p)) if dataset_crs.as_ref().is_some_and(|d| d.key() == crs.key()) => p,
                _ => continue,
            };
            names.push(f.images.name.clone());
            src.push([im.c2w[0][3], im.c2w[1][3], im.c2w[2][3]]);
            dst.push(target);
        }
        let fit = match &control {
            None => georef::robust_fit(&names, &src, &dst, o.gps_error_m),
            Some(gc) => {
                let (placed, notes) = super::control::place(&model, gc);
                georef::fit_with_control(&names, &src, &dst, o.gps_error_m, &placed, notes)
            }
        }
        .map_err(|e| {
            dataset_err(&tpath, format!("geo-registration to GPS: {e}; pass --no-georef to keep COLMAP's frame"))
        })?;
        let mut fit = fit;
        georef::apply(&mut model, &fit.similarity);
        if let (Some(gc), Some(report)) = (&control, fit.control.as_mut()) {
            if !o.no_adjust {
                adjust_on_control(&mut model, &cm, gc, report, (&names, &dst, &fit.rejected), o.gps_error_m)
                    .map_err(|e| dataset_err(&tpath, format!("bundle adjustment on the ground control: {e}")))?;
            }
        }
        model.crs = Some(crs);
        georef_fit = Some(fit);
    }

    let rep = crate::poses::apply_poses_to(&model, &model_dir, &tpath, root)?;
    seconds.insert("total".into(), t_all.elapsed().as_secs_f64());
    let report = SfmReport {
        colmap: colmap.version.clone(),
        workspace: ws.clone(),
        band: band_desc,
        upsample: factor,
        matcher,
        intrinsics,
        frames: frames.len(),
        registered: rep.registered,
        unregistered: rep.unregistered.clone(),
        points: rep.points,
        mean_reprojection_error_px: rep.mean_reprojection_error_px,
        mean_track_length: rep.mean_track_length,
        models,
        georef: georef_fit,
        crs: rep.crs.clone(),
        seconds,
        backup: rep.backup.clone(),
    };
    let text = serde_json::to_string_pretty(&json!(report)).expect("plain data");
    crate::util::atomic::write_bytes(&ws.join("sfm_report.json"), text.as_bytes())
        .map_err(|e| dataset_err(&ws.join("sfm_report.json"), e.to_string()))?;
    Ok(report)
}

/// Runs [`super::adjusted::adjust_with_control`] on the georeferenced `model` with the points of `gc` placed again
/// in its frame and the GPS pairs (`names`, `fixes`) the fit kept, and puts the adjusted residuals into `report`.
fn adjust_on_control(
    model: &mut crate::poses::model::PoseModel,
    cm: &ColmapModel,
    gc: &super::control::GroundControl,
    report: &mut georef::ControlReport,
    (names, fixes, rejected): (&[String], &[[f64; 3]], &[String]),
    gps_sigma: f64,
) -> Result<(), String> {
    let (placed, _) = super::control::place(model, gc);
    if placed.is_empty() {
        return Ok(());
    }
    let by_stem: HashMap<String, usize> = model.images.iter().enumerate().map(|(i, im)| (stem(&im.name), i)).collect();
    let gps: Vec<(usize, [f64; 3])> = names
        .iter()
        .zip(fixes)
        .filter(|(n, _)| !rejected.contains(n))
        .filter_map(|(n, f)| by_stem.get(&stem(n)).map(|&i| (i, *f)))
        .collect();
    let super::adjusted::Adjusted { report: mut adj, points, gps_shift_m: offset } =
        super::adjusted::adjust_with_control(model, cm, &gps, gps_sigma, &placed)?;
    adj.similarity_rms_m = report.rms_m;
    adj.similarity_check_rms_m = report.check_rms_m;
    report.set_points(points);
    if offset.is_some() {
        report.gps_shift_m = offset;
    }
    report.adjustment = Some(adj);
    Ok(())
}
