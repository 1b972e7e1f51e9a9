//! `msnerf dataset register IN --out OUT`: band-to-band registration of a dataset that is already in msnerf's
//! format (made by other software, or a simulated rig): every band of every frame is aligned to the reference band
//! by the import's homography alignment ([`super::register::align`], the ECC-equivalent Gauss-Newton on gradient
//! images; `field: true` adds the residual shift field) and resampled once, bilinearly. This is the 2D answer to a
//! rig's band offsets, what ODM and Metashape apply; rig-aware training (`rig_cameras`) is the 3D one, and
//! docs/radiometry.md compares them.
//!
//! OUT holds one float32 TIFF per frame (`images/`), a mask per frame (`masks/`: 0 where a band's warp left the
//! image, so no pixel trains on a band it does not have) and `transforms.json`: the input's, minus `rig_cameras`,
//! with absolute paths to the input's depth maps and sparse points and `registration_residual_px` per frame.
//! Written into a staging folder and renamed into place when complete.

use std::path::{Path, PathBuf};

use super::frame::{median_warps, BandRegistration};
use super::plane::Plane;
use super::register::{align, gradient_image, residual_shift, warp_plane, Homography};
use super::warp::Warp;
use super::RigError;
use crate::data::{load_dataset, LoadOptions};
use crate::util::staging::StagingDir;

/// What `dataset register` did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RegisterSummary {
    pub frames: usize,
    pub reference_band: String,
    /// Largest residual per band over the frames (pixels; 0 for the reference band).
    pub max_residual_px: Vec<f64>,
    pub seconds: f64,
}

/// Options: the reference band by name (`None`: the band nearest 560 nm, as the import picks, among those seen
/// through the frame camera when the dataset has `rig_cameras`), whether to fit the residual field, whether to share
/// one warp per band.
#[derive(Debug, Clone, Default)]
pub struct RegisterOptions {
    pub reference_band: Option<String>,
    pub field: bool,
    /// One warp per band for every frame: the element-wise median of the frames' own warps, as `import rig
    /// --register rig` and ODM's one alignment matrix per band (robust to a frame where the alignment failed).
    pub shared: bool,
    pub overwrite: bool,
}

fn out_err(path: &Path, reason: impl std::fmt::Display) -> RigError {
    RigError::Output { path: path.to_path_buf(), reason: reason.to_string() }
}

/// Registers the dataset at `input` into `out`.
pub fn register_dataset(input: &Path, out: &Path, opts: &RegisterOptions) -> Result<RegisterSummary, RigError> {
    let t0 = std::time::Instant::now();
    let ds = load_dataset(input, &LoadOptions::default())
        .map_err(|e| RigError::Output { path: input.to_path_buf(), reason: e.to_string() })?;
    let b_n = ds.n_bands();
    let reference = match &opts.reference_band {
        Some(name) => ds.bands.iter().position(|b| b.name.eq_ignore_ascii_case(name)).ok_or_else(|| {
            let names: Vec<&str> = ds.bands.iter().map(|b| b.name.as_str()).collect();
            RigError::option("--reference-band", format!("`{name}` is not a band ({})", names.join(", ")))
        })?,
        // The band nearest 560 nm (as the import picks green) among those seen through the frame camera.
        None => (0..b_n)
            .filter(|&b| ds.band_camera(b).is_none_or(|c| c.is_frame_camera(&ds.frames[0].camera)))
            .min_by(|&a, &b| {
                let d = |i: usize| (ds.bands[i].center_nm.unwrap_or(560.0) - 560.0).abs();
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0),
    };
    // The registered images take the frames' pose and intrinsics: the reference band must be seen through them.
    if let Some(c) = ds.band_camera(reference) {
        if let Some(f) = ds.frames.iter().find(|f| !c.is_frame_camera(&f.camera)) {
            return Err(RigError::option(
                "--reference-band",
                format!(
                    "{}: band `{}` is not seen by the frame camera of {} (its rig_from_band or intrinsics differ), so \
                     bands registered to it would not match the frames' poses: name a band whose camera is the frame \
                     camera, or train rig-aware without registering",
                    ds.transforms_path.display(),
                    ds.bands[reference].name,
                    f.name
                ),
            ));
        }
    }
    let stage = StagingDir::new(out, opts.overwrite).map_err(|e| out_err(out, e))?;
    for d in ["images", "masks"] {
        let p = stage.path.join(d);
        std::fs::create_dir_all(&p).map_err(RigError::io(&p))?;
    }
    let text = std::fs::read_to_string(&ds.transforms_path).map_err(RigError::io(&ds.transforms_path))?;
    let mut doc: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| out_err(&ds.transforms_path, format!("invalid JSON: {e}")))?;
    let (w, h) = (ds.width as usize, ds.height as usize);
    let planes_of = |fi: usize| -> Result<(crate::data::Raster, Vec<Plane>), RigError> {
        let raster = ds.read_frame(fi).map_err(|e| out_err(ds.image_path(fi), e))?;
        let planes = (0..b_n)
            .map(|b| {
                let mut v = Vec::with_capacity(w * h);
                for row in 0..h as u32 {
                    for col in 0..w as u32 {
                        v.push(raster.get(row, col, b));
                    }
                }
                Plane::new(w, h, v)
            })
            .collect();
        Ok((raster, planes))
    };
    // Each frame's own warps; with `shared`, all of them first (a second read of every frame then resamples
    // with their median), else each frame is resampled as soon as its warps are known (one read).
    let align_frame = |planes: &[Plane]| -> Vec<BandRegistration> {
        (0..b_n)
            .map(|b| {
                let warp = if b == reference {
                    Warp::identity()
                } else {
                    let (warp, _) = align(&planes[reference], &planes[b], Homography::IDENTITY);
                    if opts.field {
                        warp
                    } else {
                        Warp::from_homography(warp.homography)
                    }
                };
                BandRegistration { band: ds.bands[b].name.clone(), warp, stats: None }
            })
            .collect()
    };
    let shared = if opts.shared {
        let mut all = Vec::with_capacity(ds.frames.len());
        for fi in 0..ds.frames.len() {
            all.push(align_frame(&planes_of(fi)?.1));
        }
        Some(median_warps(&all, w, h).0)
    } else {
        None
    };
    let mut max_residual = vec![0.0f64; b_n];
    let mut frames_out: Vec<(usize, String, Vec<f64>)> = Vec::with_capacity(ds.frames.len());
    for (fi, frame) in ds.frames.iter().enumerate() {
        let (raster, planes) = planes_of(fi)?;
        let own_warps;
        let warps = match &shared {
            Some(s) => s,
            None => {
                own_warps = align_frame(&planes);
                &own_warps
            }
        };
        let mut out = vec![0.0f32; w * h * b_n];
        let mut mask: Vec<u8> =
            (0..w * h).map(|p| if raster.mask_at((p / w) as u32, (p % w) as u32) == 0 { 0 } else { 255 }).collect();
        let mut residuals = vec![0.0f64; b_n];
        for b in 0..b_n {
            let warp = &warps[b].warp;
            let warped = if b == reference { planes[b].clone() } else { warp_plane(&planes[b], warp, w, h) };
            if b != reference {
                // Measured on gradient images, as the import does (edges agree across bands, intensities need not).
                residuals[b] = residual_shift(&gradient_image(&planes[reference]), &gradient_image(&planes[b]), warp);
            }
            for (p, &v) in warped.data.iter().enumerate() {
                if v.is_finite() {
                    out[p * b_n + b] = v;
                } else {
                    mask[p] = 0;
                }
            }
            max_residual[b] = max_residual[b].max(residuals[b]);
        }
        // The frame's own file stem (so per-frame truth and reports still match by name); its index if taken.
        let own = Path::new(&frame.name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let stem = if own.is_empty() || frames_out.iter().any(|f| f.1 == own) { format!("frame_{fi:05}") } else { own };
        let img = stage.path.join(format!("images/{stem}.tif"));
        crate::util::tiff::write_tiff(&img, w as u32, h as u32, b_n, crate::util::tiff::TiffData::F32(&out))
            .map_err(RigError::io(&img))?;
        let mpath = stage.path.join(format!("masks/{stem}.png"));
        image::GrayImage::from_raw(w as u32, h as u32, mask)
            .expect("mask size")
            .save(&mpath)
            .map_err(|e| out_err(&mpath, e))?;
        frames_out.push((frame.index_in_file, stem, residuals));
    }
    // transforms.json: the input's frames in file order, pointing at the registered images.
    let abs = |p: &str| -> String {
        let q = Path::new(p);
        if q.is_absolute() {
            p.to_string()
        } else {
            std::path::absolute(input_dir(&ds.transforms_path).join(q))
                .unwrap_or_else(|_| input_dir(&ds.transforms_path).join(q))
                .display()
                .to_string()
        }
    };
    let top = doc.as_object_mut().ok_or_else(|| out_err(&ds.transforms_path, "top level is not an object"))?;
    top.remove("rig_cameras");
    for key in ["pixel_scale", "black_level"] {
        top.remove(key); // the registered images hold the scaled float values
    }
    if let Some(p) = top.get("sparse_points_path").and_then(|v| v.as_str()).map(abs) {
        top.insert("sparse_points_path".into(), p.into());
    }
    if let Some(bands) = top.get_mut("bands").and_then(|b| b.as_array_mut()) {
        for b in bands {
            if let Some(o) = b.as_object_mut() {
                o.remove("pixel_scale");
                o.remove("black_level");
            }
        }
    }
    let frames = top.get_mut("frames").and_then(|f| f.as_array_mut()).expect("the loader read the frames");
    for (index, stem, residuals) in &frames_out {
        let f = frames[*index].as_object_mut().expect("the loader read the frame");
        f.remove("band_files");
        f.insert("file_path".into(), format!("images/{stem}.tif").into());
        f.insert("mask_path".into(), format!("masks/{stem}.png").into());
        f.insert("registration_residual_px".into(), serde_json::json!(residuals));
        if let Some(p) = f.get("depth_file_path").and_then(|v| v.as_str()).map(abs) {
            f.insert("depth_file_path".into(), p.into());
        }
    }
    top.insert(
        "registration".into(),
        serde_json::json!({
            "method": match (opts.field, opts.shared) {
                (false, false) => "homography per frame",
                (true, false) => "homography + residual shift field per frame",
                (false, true) => "shared homography per band (median over the frames)",
                (true, true) => "shared homography + residual shift field per band (median over the frames)",
            },
            "reference_band": ds.bands[reference].name,
            "source": std::path::absolute(input).unwrap_or_else(|_| input.to_path_buf()),
        }),
    );
    let tpath = stage.path.join("transforms.json");
    let bytes = serde_json::to_vec_pretty(&doc).expect("json");
    std::fs::write(&tpath, bytes).map_err(RigError::io(&tpath))?;
    stage.commit().map_err(|e| out_err(out, e))?;
    Ok(RegisterSummary {
        frames: ds.frames.len(),
        reference_band: ds.bands[reference].name.clone(),
        max_residual_px: max_residual,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn input_dir(transforms: &Path) -> PathBuf {
    transforms.parent().unwrap_or(Path::new(".")).to_path_buf()
}
