//! `import rig --rig-cameras`: the dataset keeps every band in its own camera (no band-to-band warp) and says where
//! each camera is (`rig_cameras`, docs/dataset.md), for rig-aware training. Each band is undistorted into its own
//! pinhole (its calibrated focal length and principal point; `--no-undistort` keeps the raw image and writes the
//! distortion instead); the frame camera is the reference band's.
//!
//! The pose of band b in the reference camera (`rig_from_band`):
//! - rotation from `Camera:RigRelatives` (degrees about x, y, z, composed `R = Rx Ry Rz`, as MicaSense's
//!   `get_homography` reads them): the homography `K R_b^T R_ref K^-1` maps reference pixels to band pixels, so a
//!   band direction d_b is `R_ref^T R_b d_b` in the reference camera;
//! - translation from `Camera:RigTranslations`, the band camera's centre in metres, taken in the reference camera's
//!   axes (x right, y down, z forward) relative to the reference's own; absent: 0 (a rotation-only rig, warned).
//!
//! Both are turned from the photogrammetric axes (x right, y down, z forward) into the OpenGL axes of
//! `transform_matrix` (x right, y up, z backward) by F = diag(1, -1, -1): `R_gl = F R F`, `t_gl = F t`.

use glam::{DMat3, DVec3};
use serde_json::json;

use super::calib::BandFile;
use super::capture::Capture;
use super::error::RigError;
use super::frame::{write_sfm_png, BandRegistration, FrameOut, Loaded};
use super::lens::{resample, Target};
use super::warp::Warp;
use crate::util::tiff::{write_tiff, TiffData};

/// `Rx Ry Rz` of MicaSense's `RigRelatives` (degrees).
pub fn relatives_rotation(rel_deg: [f64; 3]) -> DMat3 {
    let [a, b, c] = rel_deg.map(f64::to_radians);
    DMat3::from_rotation_x(a) * DMat3::from_rotation_y(b) * DMat3::from_rotation_z(c)
}

/// The band camera's pose in the reference camera, OpenGL axes, row-major 4x4.
pub fn rig_from_band(reference: &BandFile, band: &BandFile) -> [[f64; 4]; 4] {
    let rot = |b: &BandFile| relatives_rotation(b.rig_relatives.unwrap_or([0.0; 3]));
    let r = rot(reference).transpose() * rot(band);
    let t = DVec3::from(band.rig_translations.unwrap_or([0.0; 3]))
        - DVec3::from(reference.rig_translations.unwrap_or([0.0; 3]));
    let f = DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
    let (r_gl, t_gl) = (f * r * f, f * t);
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().take(3).enumerate() {
        for (j, v) in row.iter_mut().take(3).enumerate() {
            *v = r_gl.col(j)[i];
        }
        row[3] = t_gl[i];
    }
    m[3] = [0.0, 0.0, 0.0, 1.0];
    m
}

/// Band `bi`'s own output camera: its calibrated pinhole (undistorted), or its raw geometry.
pub fn band_target(cap: &Capture, bi: usize, undistort: bool) -> Target {
    super::frame::target_for(cap, bi, undistort)
}

/// Checks that every band can be placed: a lens model each and rig relatives on every band or none. Returns the
/// warnings (translations missing).
pub fn check_rig(cap: &Capture) -> Result<Vec<String>, RigError> {
    for b in &cap.bands {
        if b.lens.is_none() {
            return Err(RigError::missing(
                &b.meta.path,
                "Camera:PerspectiveFocalLength + Camera:PrincipalPoint (or drone-dji:DewarpData)",
                "--rig-cameras gives every band its own camera and needs each band's calibration",
            ));
        }
    }
    if let Some(b) = cap.bands.iter().find(|b| b.rig_relatives.is_none()) {
        return Err(RigError::missing(
            &b.meta.path,
            "Camera:RigRelatives",
            "--rig-cameras needs the rig's geometry in every band file (this firmware writes none: register the bands \
             instead, without --rig-cameras)",
        ));
    }
    let mut warnings = Vec::new();
    if let Some(b) = cap.bands.iter().find(|b| b.rig_translations.is_none()) {
        warnings.push(format!(
            "{}: no Camera:RigTranslations: the band cameras are placed at the reference camera's centre (rotation only)",
            b.meta.path.display()
        ));
    }
    Ok(warnings)
}

/// The `rig_cameras` block of `transforms.json` for the flight's first capture (a rig is rigid). Pixel centres in
/// the import are at integers, in `transforms.json` at +0.5.
pub fn rig_cameras_json(cap: &Capture, ref_idx: usize, undistort: bool) -> serde_json::Value {
    let cams: Vec<serde_json::Value> = cap
        .bands
        .iter()
        .enumerate()
        .map(|(bi, b)| {
            let l = b.lens.expect("check_rig ran");
            let mut c = if undistort {
                let t = band_target(cap, bi, true);
                json!({"band": b.band_name, "camera_model": "PINHOLE", "fl_x": t.f, "fl_y": t.f, "cx": t.cx + 0.5, "cy": t.cy + 0.5})
            } else {
                json!({"band": b.band_name, "camera_model": "OPENCV", "fl_x": l.fx, "fl_y": l.fy, "cx": l.cx + 0.5,
                       "cy": l.cy + 0.5, "k1": l.k1, "k2": l.k2, "k3": l.k3, "p1": l.p1, "p2": l.p2})
            };
            c["rig_from_band"] = json!(rig_from_band(&cap.bands[ref_idx], b));
            c
        })
        .collect();
    json!({ "cameras": cams })
}

/// Writes a capture with every band in its own camera (`images/<capture>.tif`, full size, no crop) and its mask
/// (`masks/<capture>.png`: 0 where a band's undistortion leaves its raw image; those pixels hold 0).
pub fn write_frame_rig(
    cap: &Capture,
    l: &Loaded,
    ref_idx: usize,
    undistort: bool,
    dir: &std::path::Path,
) -> Result<FrameOut, RigError> {
    let nb = cap.bands.len();
    let planes: Vec<_> = (0..nb)
        .map(|bi| {
            let t = band_target(cap, bi, undistort);
            resample(&l.values[bi], &t, cap.bands[bi].lens.filter(|_| undistort).as_ref(), &Warp::identity())
        })
        .collect();
    let target = band_target(cap, ref_idx, undistort);
    let (w, h) = (target.width, target.height);
    if let Some(b) = planes.iter().position(|p| (p.width, p.height) != (w, h)) {
        return Err(RigError::Capture {
            capture: cap.key.clone(),
            reason: format!(
                "band {} is {}x{}, the reference {w}x{h}: --rig-cameras needs one image size",
                cap.bands[b].band_name, planes[b].width, planes[b].height
            ),
        });
    }
    let mut data = Vec::with_capacity(w * h * nb);
    let mut mask = vec![255u8; w * h];
    for (p, m) in mask.iter_mut().enumerate() {
        for pl in &planes {
            let v = pl.data[p];
            if v.is_finite() {
                data.push(v);
            } else {
                data.push(0.0);
                *m = 0;
            }
        }
    }
    write_sfm_png(&planes[ref_idx], (0, 0, w, h), &dir.join("sfm_images").join(format!("{}.png", cap.name())))?;
    let file = format!("images/{}.tif", cap.name());
    let path = dir.join(&file);
    write_tiff(&path, w as u32, h as u32, nb, TiffData::F32(&data))
        .map_err(|e| RigError::Output { path: path.clone(), reason: e.to_string() })?;
    let mpath = dir.join(format!("masks/{}.png", cap.name()));
    if let Some(parent) = mpath.parent() {
        std::fs::create_dir_all(parent).map_err(RigError::io(parent))?;
    }
    image::GrayImage::from_raw(w as u32, h as u32, mask.clone())
        .expect("mask size")
        .save_with_format(&mpath, image::ImageFormat::Png)
        .map_err(|e| RigError::Output { path: mpath.clone(), reason: e.to_string() })?;
    Ok(FrameOut {
        capture: cap.key.clone(),
        file,
        width: w,
        height: h,
        fx: target.f,
        cx: target.cx,
        cy: target.cy,
        saturated: l.saturated.clone(),
        registration: cap
            .bands
            .iter()
            .map(|b| BandRegistration { band: b.band_name.clone(), warp: Warp::identity(), stats: None })
            .collect(),
        value_quantiles: (0..nb)
            .map(|b| {
                let valid = data.iter().zip(mask.iter().flat_map(|m| std::iter::repeat_n(*m, nb)));
                crate::rig::flight_checks::quantiles(
                    valid.skip(b).step_by(nb * 7).filter(|(_, m)| *m > 0).map(|(v, _)| *v),
                )
            })
            .collect(),
    })
}
