//! [`simulate`]: renders every view on worker threads and writes the dataset (layout below) atomically.
//!
//! ```text
//! DIR/transforms.json          nerfstudio format + bands, depth keys (dataset.md)
//! DIR/images/view_00000.tif    B-sample TIFF (f32, or u16 with pixel_scale); with band_files:
//! DIR/images/view_00000_<band>.tif  one single-band TIFF per band
//! DIR/depth/view_00000.tif     f32 distance along the unit ray, metres
//! DIR/ground_truth.ply         visible surface samples with per-band reflectance
//! DIR/sparse_points.json       with --sparse-points: simulated SfM points and their tracks (`sparse_points_path`)
//! DIR/simulation.json          scene, options, effects and per-view gains
//! DIR/README.md                conventions
//! ```

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde_json::json;

use super::render::{Prepared, ViewImage};
use super::writer::{self, StagingDir, TiffData};
use super::{PixelFormat, SceneDesc, SimError, SimOptions, U16_SCALE};

/// A ground-truth sample: local position and material index.
type SurfacePoint = ([f64; 3], usize);

/// What a run produced.
#[derive(Debug, Clone)]
pub struct SimReport {
    pub out: PathBuf,
    pub scene: String,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub bands: usize,
    pub points: usize,
    pub effects: Vec<String>,
    pub threads: usize,
    /// Rendering and writing, seconds.
    pub seconds: f64,
}

impl fmt::Display for SimReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: scene `{}`, {} views of {}x{} px x {} bands, {} ground-truth points, effects: {}; {:.2} s on {} threads",
            self.out.display(),
            self.scene,
            self.views,
            self.width,
            self.height,
            self.bands,
            self.points,
            if self.effects.is_empty() { "none".to_string() } else { self.effects.join(", ") },
            self.seconds,
            self.threads
        )
    }
}

fn view_name(i: usize) -> String {
    format!("view_{i:05}")
}

/// File-name-safe band name.
fn safe(s: &str) -> String {
    s.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect()
}

/// Renders and writes the scene to `out` (see the module doc). Fails before writing on bad options.
pub fn simulate(desc: &SceneDesc, opts: &SimOptions, out: &Path) -> Result<SimReport, SimError> {
    let t0 = Instant::now();
    let prep = Prepared::new(desc, opts)?;
    let stage = StagingDir::new(out, opts.overwrite)?;
    let root = stage.path.clone();
    for d in ["images", "depth"] {
        std::fs::create_dir_all(root.join(d)).map_err(SimError::io(root.join(d)))?;
    }
    if prep.effects.rig_parallax.is_some() {
        let d = root.join("truth/registered");
        std::fs::create_dir_all(&d).map_err(SimError::io(d))?;
    }
    let threads = if opts.threads == 0 {
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    } else {
        opts.threads
    };
    let nv = prep.poses.len();
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let first_err: Mutex<Option<SimError>> = Mutex::new(None);
    let points: Mutex<Vec<Vec<SurfacePoint>>> = Mutex::new(vec![Vec::new(); nv]);
    // Depth maps stay in memory only when sparse points are asked for (their tracks need every view's depth).
    let depths: Mutex<Vec<Vec<f32>>> = Mutex::new(vec![Vec::new(); nv]);
    let keep_depth = opts.sparse_points.is_some();
    std::thread::scope(|s| {
        for _ in 0..threads.min(nv).max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= nv || failed.load(Ordering::Relaxed) {
                    break;
                }
                let mut img = prep.render_view(i);
                match write_view(&prep, opts, &root, i, &img) {
                    Ok(()) => {
                        if keep_depth {
                            depths.lock().expect("no panics while held")[i] = std::mem::take(&mut img.depth);
                        }
                        points.lock().expect("no panics while held")[i] = img.points;
                    }
                    Err(e) => {
                        failed.store(true, Ordering::Relaxed);
                        first_err.lock().expect("no panics while held").get_or_insert(e);
                    }
                }
            });
        }
    });
    if let Some(e) = first_err.into_inner().expect("threads joined") {
        return Err(e);
    }
    let points: Vec<([f64; 3], usize)> = points.into_inner().expect("threads joined").into_iter().flatten().collect();
    let mut sparse = None;
    if let Some(o) = &opts.sparse_points {
        let tracks = super::sparse::make_tracks(&prep, &depths.into_inner().expect("threads joined"), o);
        let names: Vec<String> = (0..nv).map(|i| frame_name(&prep, opts, i)).collect();
        let p = root.join("sparse_points.json");
        super::sparse::write(&prep, &root, &tracks, &names)
            .map_err(|e| SimError::Io { path: p, source: std::io::Error::other(e.to_string()) })?;
        sparse = Some("sparse_points.json");
    }
    write_transforms(&prep, opts, &root, sparse)?;
    write_points(&prep, &root, &points)?;
    super::truth::write_truth(&prep, &root, &points.iter().map(|(p, _)| *p).collect::<Vec<_>>())?;
    write_meta(&prep, desc, opts, &root)?;
    stage.commit()?;
    Ok(SimReport {
        out: out.to_path_buf(),
        scene: prep.name.clone(),
        views: nv,
        width: prep.camera.width,
        height: prep.camera.height,
        bands: prep.bands.len(),
        points: points.len(),
        effects: prep.effects.names().iter().map(|s| s.to_string()).collect(),
        threads,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn u16_values(img: &ViewImage) -> Vec<u16> {
    match &img.dn {
        Some(d) => d.clone(),
        None => img.values.iter().map(|&v| (v as f64 * U16_SCALE).round().clamp(0.0, 65535.0) as u16).collect(),
    }
}

fn write_view(prep: &Prepared, opts: &SimOptions, root: &Path, i: usize, img: &ViewImage) -> Result<(), SimError> {
    let (w, h) = (prep.camera.width, prep.camera.height);
    let nb = prep.bands.len();
    let name = view_name(i);
    let u16s = (opts.format == PixelFormat::U16).then(|| u16_values(img));
    if opts.band_files {
        let px = (w * h) as usize;
        for (b, band) in prep.bands.iter().enumerate() {
            let p = root.join(format!("images/{name}_{}.tif", safe(&band.name)));
            match &u16s {
                Some(v) => {
                    let plane: Vec<u16> = (0..px).map(|q| v[q * nb + b]).collect();
                    writer::write_tiff(&p, w, h, 1, TiffData::U16(&plane))?
                }
                None => {
                    let plane: Vec<f32> = (0..px).map(|q| img.values[q * nb + b]).collect();
                    writer::write_tiff(&p, w, h, 1, TiffData::F32(&plane))?
                }
            }
        }
    } else {
        let p = root.join(format!("images/{name}.tif"));
        match &u16s {
            Some(v) => writer::write_tiff(&p, w, h, nb, TiffData::U16(v))?,
            None => writer::write_tiff(&p, w, h, nb, TiffData::F32(&img.values))?,
        }
    }
    if let Some(reg) = &img.registered {
        writer::write_tiff(&root.join(format!("truth/registered/{name}.tif")), w, h, nb, TiffData::F32(reg))?;
    }
    writer::write_tiff(&root.join(format!("depth/{name}.tif")), w, h, 1, TiffData::F32(&img.depth))
}

/// `pixel_scale` of u16 output.
fn pixel_scale(prep: &Prepared) -> f64 {
    match &prep.effects.noise {
        Some(n) if n.bits > 0 => ((1u32 << n.bits) - 1) as f64 / n.full_scale,
        _ => U16_SCALE,
    }
}

fn world_pose(prep: &Prepared, m: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut m = *m;
    for (r, o) in m.iter_mut().zip(prep.world_offset) {
        r[3] += o;
    }
    m
}

/// The name `transforms.json` gives view `i` (its `file_path`, or its first band file).
fn frame_name(prep: &Prepared, opts: &SimOptions, i: usize) -> String {
    let name = view_name(i);
    if opts.band_files {
        format!("images/{name}_{}.tif", safe(&prep.bands[0].name))
    } else {
        format!("images/{name}.tif")
    }
}

fn write_transforms(prep: &Prepared, opts: &SimOptions, root: &Path, sparse: Option<&str>) -> Result<(), SimError> {
    let c = &prep.camera;
    let bands: Vec<serde_json::Value> =
        prep.bands.iter().map(|b| json!({"name": b.name, "center_nm": b.center_nm, "fwhm_nm": b.fwhm_nm})).collect();
    let frames: Vec<serde_json::Value> = prep
        .poses
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let name = view_name(i);
            let mut f = json!({
                "transform_matrix": world_pose(prep, m),
                "depth_file_path": format!("depth/{name}.tif"),
            });
            if opts.band_files {
                let files: Vec<String> =
                    prep.bands.iter().map(|b| format!("images/{name}_{}.tif", safe(&b.name))).collect();
                f["band_files"] = json!(files);
            } else {
                f["file_path"] = json!(format!("images/{name}.tif"));
            }
            f
        })
        .collect();
    let mut t = json!({
        "camera_model": "PINHOLE",
        "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": c.width, "h": c.height,
        "bands": bands,
        "depth_type": "ray_distance",
        "depth_unit_scale_factor": 1.0,
        "frames": frames,
    });
    if opts.format == PixelFormat::U16 {
        t["pixel_scale"] = json!(pixel_scale(prep));
    }
    if let Some(p) = sparse {
        t["sparse_points_path"] = json!(p);
    }
    if let Some(c) = &prep.crs {
        t["crs"] = json!(c.key());
    }
    if let Some(r) = prep.effects.rig_parallax.as_ref().filter(|r| r.write_rig_cameras) {
        let cams: Vec<serde_json::Value> = prep
            .bands
            .iter()
            .map(|b| {
                let o = r.bands.iter().find(|x| x.band.eq_ignore_ascii_case(&b.name)).map_or([0.0; 3], |x| x.offset_m);
                json!({
                    "band": b.name, "camera_model": "PINHOLE", "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy,
                    "rig_from_band": [[1.0, 0.0, 0.0, o[0]], [0.0, 1.0, 0.0, o[1]], [0.0, 0.0, 1.0, o[2]], [0.0, 0.0, 0.0, 1.0]],
                })
            })
            .collect();
        t["rig_cameras"] = json!({ "cameras": cams });
    }
    writer::write_json(&root.join("transforms.json"), &t)
}

fn write_points(prep: &Prepared, root: &Path, points: &[([f64; 3], usize)]) -> Result<(), SimError> {
    use crate::output::pointcloud::{write_ply, PlyOptions, PointCloud};
    let bands: Vec<crate::data::Band> =
        prep.bands.iter().map(|b| crate::output::image::band(&b.name, Some(b.center_nm), Some(b.fwhm_nm))).collect();
    let o = prep.world_offset;
    let xyz: Vec<[f64; 3]> = points.iter().map(|(p, _)| [p[0] + o[0], p[1] + o[1], p[2] + o[2]]).collect();
    // Textured materials: the reflectance times the texture factor at the point, as the images show it.
    let refl: Vec<f32> = points
        .iter()
        .flat_map(|(p, m)| {
            let mat = &prep.materials[*m];
            let f = mat.texture.map_or(1.0, |t| t.factor(prep.seed, *m, *p));
            mat.refl.iter().map(move |&r| (r * f) as f32)
        })
        .collect();
    let path = root.join("ground_truth.ply");
    let cloud = PointCloud::new(xyz, bands, refl)?;
    let mut comments = vec![
        format!("msnerf simulate scene {}", prep.name),
        format!("world frame: local scene frame + world_offset {} {} {} (metres, z up)", o[0], o[1], o[2]),
        "values: band-integrated Lambertian reflectance of the surface times its texture factor (no light or sensor effects)"
            .to_string(),
    ];
    if let Some(c) = &prep.crs {
        comments.push(format!("crs {}", c.key()));
        comments.push(format!("crs_wkt {}", c.wkt));
    }
    Ok(write_ply(&path, &cloud, &PlyOptions { comments, ..Default::default() })?)
}

fn write_meta(prep: &Prepared, desc: &SceneDesc, opts: &SimOptions, root: &Path) -> Result<(), SimError> {
    let nb = prep.bands.len();
    let gains: Option<Vec<Vec<f64>>> = prep
        .effects
        .exposure_drift
        .as_ref()
        .map(|_| (0..prep.poses.len()).map(|v| (0..nb).map(|b| prep.gain(v, b)).collect()).collect());
    let materials: serde_json::Map<String, serde_json::Value> = prep
        .materials
        .iter()
        .map(|m| (m.name.clone(), json!({"band_reflectance": m.refl, "vegetation": m.vegetation})))
        .collect();
    let eff = &prep.effects;
    let meta = json!({
        "scene": prep.name,
        "seed": prep.seed,
        "world_offset": prep.world_offset,
        "width": prep.camera.width,
        "height": prep.camera.height,
        "hfov_deg": desc.image.hfov_deg,
        "views": prep.poses.len(),
        "format": format!("{:?}", opts.format).to_lowercase(),
        "band_files": opts.band_files,
        "effects": eff.names(),
        "sun": eff.sun.as_ref().map(|s| json!({"azimuth_deg": s.azimuth_deg, "elevation_deg": s.elevation_deg, "sky_fraction": s.sky_fraction})),
        "vegetation_brdf": eff.vegetation_brdf.as_ref().map(|b| json!({"k": b.k, "theta": b.theta, "rho_c": b.rho_c})),
        "misregistration": eff.misregistration.as_ref().map(|m| m.bands.iter().map(|b| json!({"band": b.band, "shift_px": b.shift_px, "rotation_deg": b.rotation_deg})).collect::<Vec<_>>()),
        "rig_parallax": eff.rig_parallax.as_ref().map(|r| json!({"bands": r.bands.iter().map(|b| json!({"band": b.band, "offset_m": b.offset_m})).collect::<Vec<_>>(), "write_rig_cameras": r.write_rig_cameras})),
        "vignetting": eff.vignetting.as_ref().map(|v| json!({"coeffs": v.coeffs, "center_px": v.center_px})),
        "exposure_gains": gains,
        "noise": eff.noise.as_ref().map(|n| json!({"std": n.std, "shot": n.shot, "bits": n.bits, "full_scale": n.full_scale})),
        "materials": materials,
    });
    writer::write_json(&root.join("simulation.json"), &meta)?;
    let readme = readme(prep, opts);
    std::fs::write(root.join("README.md"), readme).map_err(SimError::io(root.join("README.md")))
}

fn readme(prep: &Prepared, opts: &SimOptions) -> String {
    let o = prep.world_offset;
    let effects = prep.effects.names();
    let bands: String =
        prep.bands.iter().map(|b| format!("| {} | {} | {} |\n", b.name, b.center_nm, b.fwhm_nm)).collect();
    let images = if opts.band_files {
        "`images/view_NNNNN_<band>.tif`: one single-band TIFF per band (`band_files` in transforms.json)"
    } else {
        "`images/view_NNNNN.tif`: one chunky TIFF with all bands, in the order of `bands`"
    };
    let values = match opts.format {
        PixelFormat::F32 => "32-bit float reflectance".to_string(),
        PixelFormat::U16 => format!("16-bit integers; reflectance = value / pixel_scale ({})", pixel_scale(prep)),
    };
    format!(
        "# Simulated dataset: scene `{name}`\n\n\
Written by `msnerf simulate` (seed {seed}). Format: spec/dataset.md (nerfstudio `transforms.json` + `bands`).\n\n\
## Conventions\n\n\
- Units: metres. World frame: the scene's local frame (x east, y north, z up, ground at z = 0) plus\n  \
`world_offset` = ({ox}, {oy}, {oz}), which is already added to every pose and point.\n\
- Poses: `transform_matrix` is camera-to-world with OpenGL camera axes (+x right, +y up, looking along -z).\n\
- Intrinsics: pinhole, fl_x = fl_y = {fx:.6}, principal point at the image centre, {w}x{h} px;\n  \
pixel (col, row) has its centre at (col + 0.5, row + 0.5); one ray per pixel through that centre (no anti-aliasing).\n\
- Images: {images}; {values}.\n\
- Depth: `depth/view_NNNNN.tif`, float32, distance along the unit ray from the camera centre, metres\n  \
(`depth_type: ray_distance`, `depth_unit_scale_factor: 1`). Rays that miss every object end on the ground disc or\n  \
on the backdrop dome (radius {extent} m), so every depth is finite.\n\
- `ground_truth.ply`: {pts_desc}; one float per band (`refl_<centre nm>`): the surface's band-integrated\n  \
reflectance with no light or sensor effect.\n\
- `simulation.json`: the options, effects, per-view gains and every material's band values.\n{registered}\n\
## Bands\n\n| name | centre nm | FWHM nm |\n|---|---|---|\n{bands}\n\
## Effects\n\n{effects_desc}\n\n\
Without effects a pixel is the band reflectance of the surface it sees (flat Lambertian light). The formulas of\n\
each effect are in the msnerf source, `src/sim/effects.rs`.\n",
        name = prep.name,
        seed = prep.seed,
        ox = o[0],
        oy = o[1],
        oz = o[2],
        fx = prep.camera.fx,
        w = prep.camera.width,
        h = prep.camera.height,
        extent = prep.world.extent,
        pts_desc = if o != [0.0; 3] {
            "binary little-endian PLY, x y z as double (world coordinates are too large for float)"
        } else {
            "binary little-endian PLY, x y z as float"
        },
        registered = if prep.effects.rig_parallax.is_some() {
            "- `truth/registered/view_NNNNN.tif` (`rig_parallax`): every band as the frame camera sees it (gains and\n  \
vignetting applied, no noise): what registered bands should show.\n"
        } else {
            ""
        },
        effects_desc = if effects.is_empty() { "None.".to_string() } else { format!("On: {}.", effects.join(", ")) },
    )
}
