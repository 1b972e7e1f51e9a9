//! `msnerf bench flight`: a processed raw flight (`msnerf process`) against the truth the simulator wrote beside it
//! (`msnerf simulate --raw-rig`), every product compared (issue 50's acceptance; `make flight-acceptance` runs it):
//!
//! - captures registered by SfM, and the CRS of every product;
//! - reflectance: every imported image's pixels on ground away from material edges against the scene's value there
//!   (reflectance times its light and texture, traced through the reference band's camera at the capture's true
//!   pose), the median ratio per band;
//! - band registration against the rig's true correspondences ([`crate::sim::sensor::registration_truth`]);
//! - the cloud against the scene's true surface points, the DSM against the true DSM, both after removing the GPS
//!   datum shift the simulation stated (no method without ground control can know it; the rest of the GPS error
//!   stays in the figures: the tilt and scale a fit to noisy GPS leaves); and both again after the best similarity
//!   of the cloud to the true surface (trimmed ICP, [`crate::output::pointcloud::icp`]): the relative accuracy,
//!   what ground control would leave; and the products as delivered, nothing removed (with ground control,
//!   `process --gcp`, the shift is not removed by the bench: the control points took it away, and the figures
//!   "after the datum shift" are the absolute ones);
//! - held-out PSNR and SSIM per band, each stage's time and peak memory against the planner's host figure;
//! - the imported images against the images the simulator wrote directly for the same captures (PSNR per band:
//!   sensor noise, resampling, radiometric error), mapped through the reference band's rotation in the rig (its
//!   few centimetres of offset from the rig's centre are left in);
//! - optionally, the same flight written directly by the simulator and trained and exported the same way, and
//!   the held-out PSNR a field as good as that one would score against the imported targets: the direct field's
//!   squared error plus the imported images' own (independent errors add), to compare with the raw flight's.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::Value;

use crate::output::compare::{compare_clouds_with, AccuracyOptions, CompareOptions};
use crate::output::pointcloud::{read_cloud, PointCloud};
use crate::output::raster::geotiff_read::read_geotiff;
use crate::sim::sensor::flight::{prepare, RawRigOptions};
use crate::sim::SceneDesc;
use crate::util::stats::nearest_rank as pct;

/// Errors of the benchmark name the file.
#[derive(Debug, thiserror::Error)]
pub enum FlightBenchError {
    #[error("{}: {reason}", path.display())]
    File { path: PathBuf, reason: String },
    #[error("{0}")]
    Other(String),
}

fn file_err(path: &Path) -> impl Fn(&dyn std::fmt::Display) -> FlightBenchError + '_ {
    move |e| FlightBenchError::File { path: path.to_path_buf(), reason: e.to_string() }
}

fn read_json(path: &Path) -> Result<Value, FlightBenchError> {
    let text = std::fs::read_to_string(path).map_err(|e| file_err(path)(&e))?;
    serde_json::from_str(&text).map_err(|e| file_err(path)(&e))
}

/// Reflectance of one band: imported over true value on ground pixels away from edges.
#[derive(Debug, Clone, Serialize)]
pub struct BandReflectance {
    pub band: String,
    pub median_ratio: f64,
    pub p10_ratio: f64,
    pub p90_ratio: f64,
    pub pixels: usize,
}

/// One band of the imported images against the directly simulated ones (values in reflectance, range 1).
#[derive(Debug, Clone, Serialize)]
pub struct BandFidelity {
    pub band: String,
    pub mse: f64,
    pub psnr_db: f64,
    pub pixels: usize,
}

/// A surface product against the truth.
#[derive(Debug, Clone, Serialize)]
pub struct SurfaceStats {
    pub count: usize,
    pub median_abs_m: f64,
    pub bias_m: f64,
    pub within_0_10: f64,
    pub within_0_25: f64,
    pub within_0_50: f64,
}

/// The whole comparison.
#[derive(Debug, Clone, Serialize)]
pub struct FlightAcceptance {
    pub flight: String,
    pub project: String,
    pub sensor: Value,
    pub captures: usize,
    pub registered: usize,
    pub crs: String,
    pub products_crs: Vec<(String, Option<u16>)>,
    /// The shift removed before the "after the datum shift" figures (zero with ground control).
    pub datum_shift_m: [f64; 3],
    pub reflectance: Vec<BandReflectance>,
    /// The imported images against the directly simulated ones of the same captures.
    pub image_fidelity: Vec<BandFidelity>,
    /// Band registration against the rig's true correspondences (raw pixels of each band).
    pub registration: crate::sim::sensor::registration_truth::RegistrationAccuracy,
    pub eval: Vec<(String, f64, f64)>,
    /// The SfM cameras against the true ones once the stated datum shift is removed: the mean offset (east, north,
    /// up, m), the scale error and the RMS of what is left after the best similarity; what ground control would remove.
    pub georeferencing: Value,
    /// The cloud's accuracy: distance of its points to the true surface (median, RMSE planar and vertical), after the
    /// stated datum shift; and after the cloud's best similarity to the true surface (the reconstruction alone).
    pub cloud: Value,
    pub cloud_relative: Value,
    pub dsm: SurfaceStats,
    pub dsm_relative: SurfaceStats,
    /// The products as delivered, nothing removed: with ground control the datum shift is gone without being told.
    pub cloud_absolute: Value,
    pub dsm_absolute: SurfaceStats,
    /// The SfM stage's ground-control report (residuals and check residuals), when the flight had ground control.
    pub ground_control: Option<Value>,
    /// The DTM against the true bare earth, after the datum shift (None when the project has no `dtm.tif`).
    pub dtm: Option<SurfaceStats>,
    /// The trees found against the scene's (`compare-trees`' figures, positions after the datum shift).
    pub trees: Option<Value>,
    /// The datum shift the simulation put into every GPS fix.
    pub simulated_shift_m: [f64; 3],
    /// That similarity (after the datum shift): rotation and tilt (degrees), scale error, translation (m), ICP RMS.
    pub relative_transform: Value,
    pub stages: Vec<Value>,
    pub direct: Option<Value>,
}

/// The raw-rig options the flight was simulated with (its truth records them).
fn flight_options(truth: &Value) -> Result<RawRigOptions, FlightBenchError> {
    let o = &truth["options"];
    let sensor: crate::sim::sensor::SensorKind = serde_json::from_value(o["sensor"].clone())
        .map_err(|e| FlightBenchError::Other(format!("truth/flight.json options.sensor: {e}")))?;
    let num = |k: &str| o[k].as_u64().ok_or_else(|| FlightBenchError::Other(format!("truth/flight.json options.{k}")));
    Ok(RawRigOptions {
        sensor,
        width: Some(num("width")? as u32),
        height: Some(num("height")? as u32),
        views: Some(num("views")? as usize),
        seed: Some(num("seed")?),
        ..Default::default()
    })
}

/// The flight's truth geometry rebuilt for a dataset imported from it: the prepared scene, the importer's reference
/// band's pose in the rig, the dataset's transforms and band names.
struct TruthGeometry {
    desc: SceneDesc,
    prep: crate::sim::render::Prepared,
    rig: crate::sim::sensor::forward::RigPose,
    t: Value,
    bands: Vec<String>,
}

fn truth_geometry(flight: &Path, dataset: &Path, truth: &Value) -> Result<TruthGeometry, FlightBenchError> {
    let scene_path = flight.join("truth/scene.yaml");
    let text = std::fs::read_to_string(&scene_path).map_err(|e| file_err(&scene_path)(&e))?;
    let desc = SceneDesc::from_yaml(&text, &scene_path.display().to_string())
        .map_err(|e| FlightBenchError::Other(e.to_string()))?;
    let (profile, _, prep, _) =
        prepare(&desc, &flight_options(truth)?).map_err(|e| FlightBenchError::Other(e.to_string()))?;
    let t = read_json(&dataset.join("transforms.json"))?;
    // The dataset's frames are the importer's reference band's camera (its rig pose in the scene's reference camera).
    let reference = t["reference_band"].as_str().unwrap_or_default();
    let rb = profile.bands.iter().find(|b| b.name == reference).ok_or_else(|| {
        FlightBenchError::Other(format!("the dataset's reference band {reference:?} is not a band of the camera"))
    })?;
    let rig = crate::sim::sensor::forward::RigPose::of(&profile, rb);
    let bands: Vec<String> =
        t["bands"].as_array().into_iter().flatten().filter_map(|b| b["name"].as_str().map(String::from)).collect();
    Ok(TruthGeometry { desc, prep, rig, t, bands })
}

/// The capture number of an imported frame (`IMG_0007.tif` -> 7).
fn capture_number(file: &str) -> Result<usize, FlightBenchError> {
    Path::new(file)
        .file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| s.rsplit('_').next())
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| FlightBenchError::Other(format!("frame {file}: not a capture's image name")))
}

/// Frames compared by [`image_fidelity`]: evenly spread over the flight.
const FIDELITY_FRAMES: usize = 16;

/// The imported images against the images the simulator wrote directly for the same captures (module doc): each
/// imported pixel's ray, turned from the reference band's camera into the rig's, sampled bilinearly in the direct
/// image. At most [`FIDELITY_FRAMES`] frames, about 320 pixels across each.
fn image_fidelity(flight: &Path, dataset: &Path, geo: &TruthGeometry) -> Result<Vec<BandFidelity>, FlightBenchError> {
    let TruthGeometry { rig, t, bands, .. } = geo;
    let direct = flight.join("truth/dataset");
    let dt = read_json(&direct.join("transforms.json"))?;
    let key = |v: &Value, k: &str| {
        v[k].as_f64().ok_or_else(|| FlightBenchError::Other(format!("{}: no top-level {k}", direct.display())))
    };
    let (tf, tcx, tcy) = (key(&dt, "fl_x")?, key(&dt, "cx")?, key(&dt, "cy")?);
    let direct_files: Vec<&str> =
        dt["frames"].as_array().into_iter().flatten().filter_map(|f| f["file_path"].as_str()).collect();
    let frames: Vec<&Value> = t["frames"].as_array().into_iter().flatten().collect();
    let stride = frames.len().div_ceil(FIDELITY_FRAMES).max(1);
    let mut sq = vec![0.0f64; bands.len()];
    let mut n = vec![0usize; bands.len()];
    for f in frames.iter().step_by(stride) {
        let file = f["file_path"].as_str().unwrap_or_default();
        let Some(view) = capture_number(file)?.checked_sub(1) else { continue };
        let Some(dfile) = direct_files.get(view) else { continue };
        let (fx, fy, cx, cy) = (f["fl_x"].as_f64(), f["fl_y"].as_f64(), f["cx"].as_f64(), f["cy"].as_f64());
        let (Some(fx), Some(fy), Some(cx), Some(cy)) = (fx, fy, cx, cy) else { continue };
        let (w, h, planes) = read_planes_normalised(&dataset.join(file))?;
        let (dw, dh, dplanes) = read_planes_normalised(&direct.join(dfile))?;
        if planes.len() != bands.len() || dplanes.len() < bands.len() {
            return Err(FlightBenchError::Other(format!(
                "frame {file}: {} bands, its direct image {dfile} {}, the dataset {}",
                planes.len(),
                dplanes.len(),
                bands.len()
            )));
        }
        let step = (w / 320).max(1);
        for row in (0..h).step_by(step) {
            for col in (0..w).step_by(step) {
                let d = rig.ref_from_band
                    * glam::DVec3::new((col as f64 + 0.5 - cx) / fx, (row as f64 + 0.5 - cy) / fy, 1.0);
                if d.z <= 0.0 {
                    continue;
                }
                let (u, v) = (tf * d.x / d.z + tcx - 0.5, tf * d.y / d.z + tcy - 0.5);
                if u < 0.0 || v < 0.0 || u >= (dw - 1) as f64 || v >= (dh - 1) as f64 {
                    continue;
                }
                let (u0, v0) = (u.floor() as usize, v.floor() as usize);
                let (a, b) = (u - u0 as f64, v - v0 as f64);
                for (bi, plane) in planes.iter().enumerate() {
                    let p = &dplanes[bi];
                    let at = |x: usize, y: usize| p[y * dw + x] as f64;
                    let want = (1.0 - b) * ((1.0 - a) * at(u0, v0) + a * at(u0 + 1, v0))
                        + b * ((1.0 - a) * at(u0, v0 + 1) + a * at(u0 + 1, v0 + 1));
                    let got = plane[row * w + col] as f64;
                    if got.is_finite() && want.is_finite() {
                        sq[bi] += (got - want) * (got - want);
                        n[bi] += 1;
                    }
                }
            }
        }
    }
    Ok(bands
        .iter()
        .enumerate()
        .map(|(b, band)| {
            let mse = sq[b] / n[b].max(1) as f64;
            BandFidelity { band: band.clone(), mse, psnr_db: -10.0 * mse.log10(), pixels: n[b] }
        })
        .collect())
}

/// Imported images against the scene (module doc).
fn reflectance(dataset: &Path, geo: &TruthGeometry) -> Result<Vec<BandReflectance>, FlightBenchError> {
    let TruthGeometry { prep, rig, t, bands, .. } = geo;
    // The scene's bands are the camera's in wavelength order, as the dataset's.
    let mut ratios: Vec<Vec<f64>> = vec![Vec::new(); bands.len()];
    let (sun, brdf) = prep.light_model();
    for f in t["frames"].as_array().into_iter().flatten() {
        let file = f["file_path"].as_str().unwrap_or_default();
        let number = capture_number(file)?;
        let Some(view) = number.checked_sub(1).filter(|v| *v < prep.poses.len()) else { continue };
        let path = dataset.join(file);
        let (w, h, planes) = read_planes_normalised(&path)?;
        let (fx, fy, cx, cy) = (f["fl_x"].as_f64(), f["fl_y"].as_f64(), f["cx"].as_f64(), f["cy"].as_f64());
        let (Some(fx), Some(fy), Some(cx), Some(cy)) = (fx, fy, cx, cy) else { continue };
        let c2w = prep.poses[view];
        let rot = |p: [f64; 3]| [0, 1, 2].map(|i| c2w[i][0] * p[0] + c2w[i][1] * p[1] + c2w[i][2] * p[2]);
        let oc = rot([rig.center.x, -rig.center.y, -rig.center.z]);
        let origin = [c2w[0][3] + oc[0], c2w[1][3] + oc[1], c2w[2][3] + oc[2]];
        let trace = |col: usize, row: usize| {
            let d =
                rig.ref_from_band * glam::DVec3::new((col as f64 + 0.5 - cx) / fx, (row as f64 + 0.5 - cy) / fy, 1.0);
            let dw = rot([d.x, -d.y, -d.z]);
            let n = (dw[0] * dw[0] + dw[1] * dw[1] + dw[2] * dw[2]).sqrt();
            prep.shade(origin, dw.map(|c| c / n), sun, brdf)
        };
        for row in (2..h.saturating_sub(2)).step_by(5) {
            for col in (2..w.saturating_sub(2)).step_by(5) {
                let (hit, light) = trace(col, row);
                if hit.kind != crate::sim::geometry::HitKind::Ground || hit.normal[2] < 0.99 {
                    continue;
                }
                // Away from material edges and shadow edges: the neighbours two pixels away see the same.
                let same = [(col - 2, row), (col + 2, row), (col, row - 2), (col, row + 2)].iter().all(|&(c, r)| {
                    let (hn, ln) = trace(c, r);
                    hn.material == hit.material && (ln / light - 1.0).abs() < 0.1
                });
                if !same {
                    continue;
                }
                for (b, plane) in planes.iter().enumerate() {
                    let truth_v = prep.materials[hit.material].refl[b] * light;
                    let v = plane[row * w + col] as f64;
                    if truth_v > 0.01 && v.is_finite() {
                        ratios[b].push(v / truth_v);
                    }
                }
            }
        }
    }
    Ok(bands
        .iter()
        .zip(ratios)
        .map(|(band, mut r)| BandReflectance {
            band: band.clone(),
            pixels: r.len(),
            p10_ratio: pct(&mut r, 0.1),
            p90_ratio: pct(&mut r, 0.9),
            median_ratio: pct(&mut r, 0.5),
        })
        .collect())
}

/// A TIFF's bands as floats in the dataset convention (integers over their type's maximum, floats as they are).
fn read_planes_normalised(path: &Path) -> Result<(usize, usize, Vec<Vec<f32>>), FlightBenchError> {
    use tiff::decoder::{Decoder, DecodingResult};
    let f = std::fs::File::open(path).map_err(|e| file_err(path)(&e))?;
    let mut d = Decoder::new(std::io::BufReader::new(f)).map_err(|e| file_err(path)(&e))?;
    let (w, h) = d.dimensions().map_err(|e| file_err(path)(&e))?;
    let v: Vec<f32> = match d.read_image().map_err(|e| file_err(path)(&e))? {
        DecodingResult::F32(v) => v,
        DecodingResult::U16(v) => v.into_iter().map(|x| x as f32 / 65535.0).collect(),
        DecodingResult::U8(v) => v.into_iter().map(|x| x as f32 / 255.0).collect(),
        _ => return Err(file_err(path)(&"not 8/16-bit or float32 samples")),
    };
    let (w, h) = (w as usize, h as usize);
    let nb = v.len() / (w * h).max(1);
    Ok((w, h, (0..nb).map(|b| (0..w * h).map(|i| v[i * nb + b]).collect()).collect()))
}

/// A map from a product's coordinates to the truth's (removing a datum shift, or a similarity).
type ToTruth<'a> = &'a dyn Fn([f64; 3]) -> [f64; 3];

/// The map that removes a constant shift.
fn unshift(shift: [f64; 3]) -> impl Fn([f64; 3]) -> [f64; 3] {
    move |p| [p[0] - shift[0], p[1] - shift[1], p[2] - shift[2]]
}

/// `products/trees.geojson` against the truth's trees (positions after removing `shift`), with the truth's classes
/// telling which false trees stand on open ground; None when either table is missing.
fn trees_against_truth(products: &Path, truth: &Path, shift: [f64; 3]) -> Result<Option<Value>, FlightBenchError> {
    use crate::products::trees::compare::{compare_trees, read_tree_table};
    let (p, t) = (products.join("trees.geojson"), truth.join("trees.geojson"));
    if !(p.is_file() && t.is_file()) {
        return Ok(None);
    }
    let mut found = read_tree_table(&p).map_err(|e| file_err(&p)(&e))?;
    found.iter_mut().for_each(|f| (f.x, f.y) = (f.x - shift[0], f.y - shift[1]));
    let known = read_tree_table(&t).map_err(|e| file_err(&t)(&e))?;
    let classes_path = truth.join("classes.tif");
    let classes = read_geotiff(&classes_path).map_err(|e| file_err(&classes_path)(&e))?;
    Ok(Some(compare_trees(&found, &known, Some(&classes), 0.5).to_json()))
}

/// A cloud file, its path named on error.
fn load_cloud(path: &Path) -> Result<PointCloud, FlightBenchError> {
    read_cloud(path).map_err(|e| file_err(path)(&e))
}

/// A cloud read from `path` (mapped by `to_truth`) against the truth's surface points.
fn cloud_stats(
    cloud: &PointCloud,
    path: &Path,
    truth: &PointCloud,
    to_truth: ToTruth,
) -> Result<Value, FlightBenchError> {
    let mut c = cloud.clone();
    for p in &mut c.positions {
        *p = to_truth(*p);
    }
    let rep = compare_clouds_with(&c, truth, &CompareOptions::default(), &AccuracyOptions::default())
        .map_err(|e| file_err(path)(&e))?;
    Ok(serde_json::json!({
        "points": rep.pred_points, "accuracy_median_m": rep.accuracy.median, "accuracy_rmse_m": rep.accuracy.rmse,
        "completeness_median_m": rep.completeness.median, "f_score": rep.f_score, "position": rep.position,
        "within": rep.within, "standard": rep.standard,
    }))
}

/// A DSM (its cells' surface points mapped by `to_truth`) against the true DSM, cell by cell (the truth cell under
/// each mapped point).
fn dsm_stats(dsm: &Path, truth: &Path, to_truth: ToTruth) -> Result<SurfaceStats, FlightBenchError> {
    let p = read_geotiff(dsm).map_err(|e| file_err(dsm)(&e))?;
    let t = read_geotiff(truth).map_err(|e| file_err(truth)(&e))?;
    let mut dz = Vec::new();
    for row in 0..p.grid.height {
        for col in 0..p.grid.width {
            let v = p.value(0, col, row);
            if p.is_nodata(v) {
                continue;
            }
            let c = p.grid.centre(col, row);
            let q = to_truth([c[0], c[1], v as f64]);
            let Some((tc, tr)) = t.grid.pixel_at(q[0], q[1]) else { continue };
            let tv = t.value(0, tc, tr);
            if t.is_nodata(tv) {
                continue;
            }
            dz.push(q[2] - tv as f64);
        }
    }
    let n = dz.len().max(1) as f64;
    let within = |x: f64| dz.iter().filter(|d| d.abs() <= x).count() as f64 / n;
    let mut abs: Vec<f64> = dz.iter().map(|d| d.abs()).collect();
    let mut signed = dz.clone();
    Ok(SurfaceStats {
        count: dz.len(),
        median_abs_m: pct(&mut abs, 0.5),
        bias_m: pct(&mut signed, 0.5),
        within_0_10: within(0.10),
        within_0_25: within(0.25),
        within_0_50: within(0.50),
    })
}

/// The similarity taking the project's SfM camera centres onto the true ones, and what it says (module doc).
fn camera_similarity(
    truth: &Value,
    transforms: &Path,
    shift: [f64; 3],
    rig: &crate::sim::sensor::forward::RigPose,
) -> Result<Value, FlightBenchError> {
    let t = read_json(transforms)?;
    let mut sfm = Vec::new();
    let mut real = Vec::new();
    // Orientations: the SfM camera's and the true one of the dataset's reference band (the rig's reference camera
    // turned by the band's rig rotation, OpenCV axes inside), both OpenGL camera-to-world.
    let mut rotations: Vec<(String, glam::DMat3, glam::DMat3)> = Vec::new();
    let g = glam::DMat3::from_diagonal(glam::DVec3::new(1.0, -1.0, -1.0));
    let rot3 = |v: &Value| -> Option<glam::DMat3> {
        let e = |i: usize, j: usize| v[i][j].as_f64();
        let rows = [[e(0, 0)?, e(0, 1)?, e(0, 2)?], [e(1, 0)?, e(1, 1)?, e(1, 2)?], [e(2, 0)?, e(2, 1)?, e(2, 2)?]];
        Some(glam::DMat3::from_cols_array_2d(&rows).transpose())
    };
    for f in t["frames"].as_array().into_iter().flatten() {
        let file = f["file_path"].as_str().unwrap_or_default();
        let Ok(n) = capture_number(file).map(|n| n as u64) else { continue };
        let Some(c) = truth["captures"].as_array().into_iter().flatten().find(|c| c["number"].as_u64() == Some(n))
        else {
            continue;
        };
        let m = &f["transform_matrix"];
        let r = &c["reference_c2w"];
        let at = |v: &Value, i: usize| v[i][3].as_f64();
        let (Some(rs), Some(rr)) = (rot3(m), rot3(r)) else { continue };
        if let (Some(a), Some(b), Some(c0), Some(d), Some(e), Some(h)) =
            (at(m, 0), at(m, 1), at(m, 2), at(r, 0), at(r, 1), at(r, 2))
        {
            // The band camera's true centre: the reference camera's plus its rig offset (OpenCV axes inside).
            let off = rr * (g * rig.center);
            sfm.push([a, b, c0]);
            real.push([d + off.x, e + off.y, h + off.z]);
            rotations.push((file.to_string(), rs, rr * g * rig.ref_from_band * g));
        }
    }
    let sim = crate::maths::similarity::fit_similarity(&sfm, &real).ok_or_else(|| {
        FlightBenchError::Other(format!("{}: too few posed frames to compare with the truth", transforms.display()))
    })?;
    let n = sfm.len().max(1) as f64;
    let offset: [f64; 3] =
        std::array::from_fn(|k| sfm.iter().zip(&real).map(|(a, b)| a[k] - shift[k] - b[k]).sum::<f64>() / n);
    let rms = (sfm
        .iter()
        .zip(&real)
        .map(|(a, b)| {
            let q = sim.apply(*a);
            (0..3).map(|k| (q[k] - b[k]).powi(2)).sum::<f64>()
        })
        .sum::<f64>()
        / n)
        .sqrt();
    let (angle, tilt) = crate::output::pointcloud::icp::rotation_angles(&sim);
    // Each camera's orientation error once the similarity's rotation is applied.
    let s_rot = glam::DMat3::from_cols_array_2d(&sim.rotation).transpose();
    let errs: Vec<(String, f64)> = rotations
        .iter()
        .map(|(name, rs, rt)| {
            let d = rt.transpose() * s_rot * *rs;
            let cos = ((d.x_axis.x + d.y_axis.y + d.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
            (name.clone(), cos.acos().to_degrees())
        })
        .collect();
    let rot_rms = (errs.iter().map(|e| e.1 * e.1).sum::<f64>() / errs.len().max(1) as f64).sqrt();
    let worst = errs.iter().max_by(|a, b| a.1.total_cmp(&b.1));
    Ok(serde_json::json!({
        "frames": sfm.len(), "mean_offset_after_datum_shift_m": offset, "scale_error": 1.0 / sim.scale - 1.0,
        "rotation_deg": angle, "tilt_deg": tilt, "rms_after_similarity_m": rms,
        "orientation_rms_deg": rot_rms, "orientation_worst": worst.map(|w| serde_json::json!({"frame": w.0, "deg": w.1})),
    }))
}

/// Source points ICP uses: the cloud thinned to about this many.
const ICP_POINTS: usize = 20_000;

/// The cloud's best similarity to the true surface after the datum shift (trimmed ICP) and what it says.
fn relative_similarity(
    c: &PointCloud,
    path: &Path,
    r: &PointCloud,
    shift: [f64; 3],
) -> Result<(crate::maths::similarity::Similarity, Value), FlightBenchError> {
    use crate::output::pointcloud::icp::{icp_similarity, identity, rotation_angles, IcpOptions};
    let stride = c.positions.len().div_ceil(ICP_POINTS).max(1);
    let src: Vec<[f64; 3]> = c.positions.iter().step_by(stride).map(|&p| unshift(shift)(p)).collect();
    let tree = crate::output::pointcloud::kdtree::KdTree::new(&r.positions);
    let res = icp_similarity(&src, &r.positions, &tree, identity(), &IcpOptions::default())
        .ok_or_else(|| file_err(path)(&"too few points to lay on the true surface"))?;
    let s = res.similarity;
    let (angle, tilt) = rotation_angles(&s);
    // The translation at the cloud's centre (the similarity's own is about the CRS origin, far away).
    let n = src.len().max(1) as f64;
    let centre: [f64; 3] = std::array::from_fn(|k| src.iter().map(|p| p[k]).sum::<f64>() / n);
    let moved = s.apply(centre);
    Ok((
        s,
        serde_json::json!({
            "points": src.len(), "iterations": res.iterations, "rms_m": res.rms, "rotation_deg": angle,
            "tilt_deg": tilt, "scale_error": 1.0 / s.scale - 1.0,
            "shift_at_centre_m": [moved[0] - centre[0], moved[1] - centre[1], moved[2] - centre[2]],
        }),
    ))
}

/// Compares the project with the flight's truth; `direct`: a run folder trained on `truth/dataset` whose products
/// (`cloud.las`, `dsm.tif`) lie in `direct_products`.
pub fn flight_acceptance(
    flight: &Path,
    project: &Path,
    direct: Option<(&Path, &Path)>,
) -> Result<FlightAcceptance, FlightBenchError> {
    let truth = read_json(&flight.join("truth/flight.json"))?;
    let stage = |s: &str| read_json(&project.join(format!("stages/{s}.json")));
    let poses = stage("poses")?;
    // The GPS's datum shift, which georeferencing by GPS alone keeps and ground control removes.
    let simulated_shift_m: [f64; 3] = serde_json::from_value(truth["gps"]["datum_shift_m"].clone())
        .map_err(|e| FlightBenchError::Other(format!("truth/flight.json gps.datum_shift_m: {e}")))?;
    let shift = if poses["summary"]["georef"]["control"].is_object() { [0.0; 3] } else { simulated_shift_m };
    let captures = truth["captures"].as_array().map_or(0, |c| c.iter().filter(|c| c["kind"] == "flight").count());
    let products = project.join("products");
    let products_crs = ["dsm.tif", "ortho.tif"]
        .iter()
        .map(|f| {
            let g = crate::output::raster::geotiff_read::read_grid(&products.join(f)).ok();
            (f.to_string(), g.and_then(|g| g.epsg))
        })
        .collect();
    let eval = read_json(&project.join("run/eval.json"))?;
    let eval: Vec<(String, f64, f64)> = eval["bands"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|b| {
            (
                b["name"].as_str().unwrap_or("").to_string(),
                b["psnr"].as_f64().unwrap_or(f64::NAN),
                b["ssim"].as_f64().unwrap_or(f64::NAN),
            )
        })
        .collect();
    let truth_cloud = flight.join("truth/dataset/ground_truth.ply");
    let truth_dsm = flight.join("truth/dataset/truth/dsm.tif");
    let stages: Vec<Value> = crate::process::Stage::ALL
        .iter()
        .filter_map(|s| stage(s.name()).ok())
        .map(|r| {
            serde_json::json!({
                "stage": r["stage"], "seconds": r["seconds"], "peak_host_bytes": r["peak_host_bytes"],
                "peak_gpu_bytes": r["peak_gpu_bytes"],
                "planned_host_bytes": r["summary"]["planned_host_bytes"], "planned_vram_bytes": r["summary"]["planned_vram_bytes"],
            })
        })
        .collect();
    let dataset = project.join("dataset");
    let geo = truth_geometry(flight, &dataset, &truth)?;
    let georeferencing = camera_similarity(&truth, &dataset.join("transforms.json"), shift, &geo.rig)?;
    let cloud_path = products.join("cloud.las");
    let cloud = load_cloud(&cloud_path)?;
    let truth_points = load_cloud(&truth_cloud)?;
    let (rel, relative_transform) = relative_similarity(&cloud, &cloud_path, &truth_points, shift)?;
    let fidelity = image_fidelity(flight, &dataset, &geo)?;
    let direct = match direct {
        None => None,
        Some((run, prods)) => {
            let e = read_json(&run.join("eval.json"))?;
            // A field as good as the direct one, scored against the imported targets: its squared error plus theirs.
            let expected: Vec<Value> = e["bands"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|b| {
                    let name = b["name"].as_str()?;
                    let fid = fidelity.iter().find(|f| f.band == name)?;
                    let mse = 10f64.powf(-b["psnr"].as_f64()? / 10.0) + fid.mse;
                    Some(serde_json::json!({"band": name, "psnr_db": -10.0 * mse.log10()}))
                })
                .collect();
            let p = prods.join("cloud.las");
            let direct_cloud = cloud_stats(&load_cloud(&p)?, &p, &truth_points, &unshift([0.0; 3]))?;
            Some(serde_json::json!({
                "eval": e["bands"],
                "expected_raw_psnr": expected,
                "cloud": direct_cloud,
                "dsm": dsm_stats(&prods.join("dsm.tif"), &truth_dsm, &unshift([0.0; 3]))?,
            }))
        }
    };
    Ok(FlightAcceptance {
        flight: flight.display().to_string(),
        project: project.display().to_string(),
        sensor: truth["sensor"].clone(),
        captures,
        registered: poses["summary"]["registered"].as_u64().unwrap_or(0) as usize,
        crs: truth["crs"].as_str().unwrap_or_default().to_string(),
        products_crs,
        datum_shift_m: shift,
        reflectance: reflectance(&dataset, &geo)?,
        image_fidelity: fidelity,
        registration: {
            let o = crate::sim::sensor::registration_truth::RegistrationTruthOptions {
                grid: 20,
                scene: Some(geo.desc.clone()),
            };
            crate::sim::sensor::registration_truth::evaluate_registration(flight, &dataset, &o)
                .map_err(|e| FlightBenchError::Other(format!("registration against the truth: {e}")))?
        },
        eval,
        cloud: cloud_stats(&cloud, &cloud_path, &truth_points, &unshift(shift))?,
        dsm: dsm_stats(&products.join("dsm.tif"), &truth_dsm, &unshift(shift))?,
        cloud_relative: cloud_stats(&cloud, &cloud_path, &truth_points, &|p| rel.apply(unshift(shift)(p)))?,
        dsm_relative: dsm_stats(&products.join("dsm.tif"), &truth_dsm, &|p| rel.apply(unshift(shift)(p)))?,
        cloud_absolute: cloud_stats(&cloud, &cloud_path, &truth_points, &unshift([0.0; 3]))?,
        dsm_absolute: dsm_stats(&products.join("dsm.tif"), &truth_dsm, &unshift([0.0; 3]))?,
        ground_control: Some(poses["summary"]["georef"]["control"].clone()).filter(|c| c.is_object()),
        dtm: {
            let (p, t) = (products.join("dtm.tif"), flight.join("truth/dataset/truth/dtm.tif"));
            (p.is_file() && t.is_file()).then(|| dsm_stats(&p, &t, &unshift(shift))).transpose()?
        },
        trees: trees_against_truth(&products, &flight.join("truth/dataset/truth"), shift)?,
        simulated_shift_m,
        relative_transform,
        georeferencing,
        stages,
        direct,
    })
}

impl FlightAcceptance {
    /// The figures as a plain-text table.
    pub fn table(&self) -> String {
        let mut s = format!(
            "flight {} -> project {}\ncaptures registered {} of {}; crs {}; products {:?}\ndatum shift removed {:?} m\n",
            self.flight, self.project, self.registered, self.captures, self.crs, self.products_crs, self.datum_shift_m
        );
        s += "reflectance (imported / true, ground away from edges): band median [p10, p90] pixels\n";
        for r in &self.reflectance {
            s += &format!(
                "  {:<10} {:.4} [{:.4}, {:.4}] {}\n",
                r.band, r.median_ratio, r.p10_ratio, r.p90_ratio, r.pixels
            );
        }
        s += "imported images against the directly simulated ones: band PSNR (pixels)\n";
        for f in &self.image_fidelity {
            s += &format!("  {:<10} {:.2} dB ({})\n", f.band, f.psnr_db, f.pixels);
        }
        s += &self.registration.table();
        s += "held-out PSNR / SSIM per band:";
        for (b, p, q) in &self.eval {
            s += &format!(" {b} {p:.2} dB / {q:.3};");
        }
        s += &format!(
            "\ncloud: {} points, median distance to the true surface {:.3} m, F-score {:.3}\n",
            self.cloud["points"],
            self.cloud["accuracy_median_m"].as_f64().unwrap_or(f64::NAN),
            self.cloud["f_score"].as_f64().unwrap_or(f64::NAN)
        );
        s += &format!("georeferencing (SfM cameras against the true ones): {}\n", self.georeferencing);
        s += &format!(
            "relative (after the cloud's best similarity to the true surface, {}): cloud median {:.3} m; DSM median \
             |dz| {:.3} m, bias {:+.3} m, within 0.10 m {:.1} %\n",
            self.relative_transform,
            self.cloud_relative["accuracy_median_m"].as_f64().unwrap_or(f64::NAN),
            self.dsm_relative.median_abs_m,
            self.dsm_relative.bias_m,
            100.0 * self.dsm_relative.within_0_10
        );
        let d = &self.dsm;
        s += &format!(
            "DSM: {} cells, median |dz| {:.3} m, bias {:+.3} m, within 0.10/0.25/0.50 m {:.1}/{:.1}/{:.1} %\n",
            d.count,
            d.median_abs_m,
            d.bias_m,
            100.0 * d.within_0_10,
            100.0 * d.within_0_25,
            100.0 * d.within_0_50
        );
        s += &format!(
            "absolute (the products as delivered, no shift removed): cloud median {:.3} m; DSM median |dz| {:.3} m, \
             bias {:+.3} m, within 0.10 m {:.1} %\n",
            self.cloud_absolute["accuracy_median_m"].as_f64().unwrap_or(f64::NAN),
            self.dsm_absolute.median_abs_m,
            self.dsm_absolute.bias_m,
            100.0 * self.dsm_absolute.within_0_10
        );
        if let Some(d) = &self.dtm {
            s += &format!(
                "DTM against the true bare earth: {} cells, median |dz| {:.3} m, bias {:+.3} m, within 0.10/0.25 m \
                 {:.1}/{:.1} %\n",
                d.count,
                d.median_abs_m,
                d.bias_m,
                100.0 * d.within_0_10,
                100.0 * d.within_0_25
            );
        }
        if let Some(t) = &self.trees {
            s += &format!(
                "trees: {} known, {} found, {} matched, {} false ({} on open ground); heights within 0.5 m {:.1} % \
                 (median |error| {:.3} m)\n",
                t["known"],
                t["found"],
                t["matched"],
                t["false_trees"].as_array().map_or(0, |a| a.len()),
                t["false_on_ground"],
                100.0 * t["within_tolerance"].as_f64().unwrap_or(0.0),
                t["median_abs_height_error"].as_f64().unwrap_or(f64::NAN)
            );
        }
        if let Some(c) = &self.ground_control {
            s += &format!(
                "ground control: {} point(s), residual RMS {:.3} m, check RMS {:.3} m; GPS datum shift found {} m \
                 (simulated {:?} m)\n",
                c["points"].as_array().map_or(0, |p| p.len()),
                c["rms_m"].as_f64().unwrap_or(f64::NAN),
                c["check_rms_m"].as_f64().unwrap_or(f64::NAN),
                c["gps_shift_m"],
                self.simulated_shift_m
            );
        }
        for st in &self.stages {
            s += &format!(
                "stage {}: {:.1} s, peak host {} MiB{}, GPU {} MiB\n",
                st["stage"].as_str().unwrap_or(""),
                st["seconds"].as_f64().unwrap_or(0.0),
                st["peak_host_bytes"].as_f64().map_or("n/a".into(), |b| format!("{:.0}", b / 1048576.0)),
                st["planned_host_bytes"].as_f64().map_or(String::new(), |b| format!(" (planned {:.0})", b / 1048576.0)),
                st["peak_gpu_bytes"].as_f64().map_or("n/a".into(), |b| format!("{:.0}", b / 1048576.0)),
            );
        }
        if let Some(d) = &self.direct {
            s +=
                "direct (the same flight written by the simulator): held-out PSNR; a field as good scored against the \
                  imported targets; the raw flight's\n";
            for b in d["eval"].as_array().into_iter().flatten() {
                let name = b["name"].as_str().unwrap_or("");
                let exp = d["expected_raw_psnr"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .find(|e| e["band"] == name)
                    .and_then(|e| e["psnr_db"].as_f64());
                let raw = self.eval.iter().find(|e| e.0 == name).map(|e| e.1);
                s += &format!(
                    "  {:<10} {:.2} dB; {} dB; {} dB\n",
                    name,
                    b["psnr"].as_f64().unwrap_or(f64::NAN),
                    exp.map_or("n/a".into(), |v| format!("{v:.2}")),
                    raw.map_or("n/a".into(), |v| format!("{v:.2}"))
                );
            }
            s += &format!(
                "  cloud median {:.3} m; DSM median |dz| {:.3} m, bias {:+.3} m\n",
                d["cloud"]["accuracy_median_m"].as_f64().unwrap_or(f64::NAN),
                d["dsm"]["median_abs_m"].as_f64().unwrap_or(f64::NAN),
                d["dsm"]["bias_m"].as_f64().unwrap_or(f64::NAN)
            );
        }
        s
    }
}
