//! `rig_cameras`: the per-band cameras of a multi-camera rig (issue 19, rig-aware training). A MicaSense, DJI P4M or
//! MS600Pro capture is B single-band cameras fixed to one body a few centimetres apart. A 2D warp between their
//! images is exact at one depth only; a radiance field needs none: each band's rays come from that band's own
//! camera, and each ray is compared with the one band it observed.
//!
//! ```json
//! "rig_cameras": {
//!   "cameras": [
//!     {"band": "Blue", "camera_model": "OPENCV", "fl_x": 1449.2, "fl_y": 1449.2, "cx": 640.5, "cy": 480.1,
//!      "k1": -0.1, "rig_from_band": [[1,0,0,0.021],[0,1,0,0.0],[0,0,1,0],[0,0,0,1]]},
//!     ...
//!   ]
//! }
//! ```
//!
//! One entry per band of the files (by name, any order). `rig_from_band` is the band camera's pose in the frame
//! camera's axes (4x4 or 3x4, OpenGL camera axes as `transform_matrix`, translation in the dataset's world units:
//! metres for every dataset with a `crs`). A frame's `transform_matrix` and intrinsics are then the *frame camera*,
//! where msnerf renders its registered outputs (renders, clouds, orthophotos); it is usually the reference band's
//! camera (identity `rig_from_band`, same intrinsics). Band b of a frame is seen by the camera
//! `transform_matrix · rig_from_band_b` with the band's intrinsics, at the dataset's image size.

use serde_json::{Map, Value};

use super::camera::{Camera, CameraModel, Distortion};
use super::pose::Mat4;
use super::transforms::{camera_model, implausible_focal, rigid_matrix, Ctx};

/// One band's camera as written (band by name).
#[derive(Debug, Clone, PartialEq)]
pub struct RawBandCamera {
    pub band: String,
    /// Intrinsics; `width`/`height` are 0 until the loader sets the dataset's size.
    pub camera: Camera,
    pub rig_from_band: Mat4,
}

/// The `rig_cameras` block as written.
#[derive(Debug, Clone, PartialEq)]
pub struct RawRig {
    pub cameras: Vec<RawBandCamera>,
}

/// One band's camera, resolved against the dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct BandCamera {
    pub camera: Camera,
    pub rig_from_band: Mat4,
}

impl BandCamera {
    /// Whether this band sees through the frame camera itself (identity pose and the frame's intrinsics): its rays
    /// are the frame's rays, so the frame's depth maps and sparse points apply to it.
    pub fn is_frame_camera(&self, frame: &Camera) -> bool {
        let id = (0..4).all(|i| (0..4).all(|j| (self.rig_from_band[i][j] - f64::from(u8::from(i == j))).abs() < 1e-9));
        id && self.camera == *frame
    }
}

/// The rig, one camera per band of the files, in file band order.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCameras {
    pub cameras: Vec<BandCamera>,
}

fn model_of(cx: &mut Ctx, o: &Map<String, Value>, key: &str, distortion: &Distortion) -> CameraModel {
    let name = cx.string(o, "camera_model", None);
    camera_model(name.as_deref(), distortion).unwrap_or_else(|reason| {
        cx.invalid(&format!("{key}.camera_model"), None, reason);
        CameraModel::Pinhole
    })
}

fn parse_camera(cx: &mut Ctx, i: usize, v: &Value) -> Option<RawBandCamera> {
    let key = format!("rig_cameras.cameras[{i}]");
    let Some(o) = v.as_object() else {
        cx.invalid(&key, None, "expected an object {band, fl_x, fl_y, cx, cy, rig_from_band, ...}");
        return None;
    };
    let before = cx.errors.len();
    let band = cx.string(o, "band", None);
    if band.is_none() && !o.contains_key("band") {
        cx.missing(&format!("{key}.band"), None);
    }
    let mut k = [0.0; 4];
    for (slot, name) in k.iter_mut().zip(["fl_x", "fl_y", "cx", "cy"]) {
        match cx.num(o, name, None) {
            Some(v) => *slot = v,
            None if name == "fl_y" && o.contains_key("fl_x") => *slot = f64::NAN,
            None => {
                if !o.contains_key(name) {
                    cx.missing(&format!("{key}.{name}"), None);
                }
            }
        }
    }
    if k[1].is_nan() {
        k[1] = k[0];
    }
    for (v, name) in [(k[0], "fl_x"), (k[1], "fl_y")] {
        if v <= 0.0 && o.contains_key(name) {
            cx.invalid(&format!("{key}.{name}"), None, format!("focal length must be positive, got {v}"));
        }
    }
    let mut d = [0.0; 6];
    for (slot, name) in d.iter_mut().zip(["k1", "k2", "k3", "k4", "p1", "p2"]) {
        *slot = cx.num(o, name, None).unwrap_or(0.0);
    }
    let distortion = Distortion { k1: d[0], k2: d[1], k3: d[2], k4: d[3], p1: d[4], p2: d[5] };
    let model = model_of(cx, o, &key, &distortion);
    let rig_from_band = match o.get("rig_from_band") {
        Some(m) => rigid_matrix(cx, m, &format!("{key}.rig_from_band"), None),
        None => {
            cx.missing(&format!("{key}.rig_from_band"), None);
            None
        }
    };
    if cx.errors.len() > before {
        return None;
    }
    Some(RawBandCamera {
        band: band?,
        camera: Camera { model, fx: k[0], fy: k[1], cx: k[2], cy: k[3], width: 0, height: 0, distortion },
        rig_from_band: rig_from_band?,
    })
}

/// Parses `rig_cameras` (absent or null: `None`); problems go to `cx`.
pub(super) fn parse(cx: &mut Ctx, top: &Map<String, Value>) -> Option<RawRig> {
    let block = match top.get("rig_cameras") {
        None | Some(Value::Null) => return None,
        Some(Value::Object(o)) => o,
        Some(_) => {
            cx.invalid("rig_cameras", None, "expected an object {cameras: [...]}");
            return None;
        }
    };
    let Some(list) = block.get("cameras").and_then(Value::as_array) else {
        cx.invalid("rig_cameras.cameras", None, "expected a list with one camera per band");
        return None;
    };
    if list.is_empty() {
        cx.invalid("rig_cameras.cameras", None, "empty list: give one camera per band");
        return None;
    }
    let cams: Vec<Option<RawBandCamera>> = list.iter().enumerate().map(|(i, v)| parse_camera(cx, i, v)).collect();
    cams.into_iter().collect::<Option<Vec<_>>>().map(|cameras| RawRig { cameras })
}

impl RawRig {
    /// Resolves the cameras against the bands the files hold (by name, case-insensitive) at the dataset's image
    /// size. Every band needs exactly one camera; the error names the key.
    pub fn resolve(&self, band_names: &[String], width: u32, height: u32) -> Result<RigCameras, (String, String)> {
        let mut out: Vec<Option<BandCamera>> = vec![None; band_names.len()];
        for (i, c) in self.cameras.iter().enumerate() {
            let key = format!("rig_cameras.cameras[{i}].band");
            let Some(b) = band_names.iter().position(|n| n.eq_ignore_ascii_case(&c.band)) else {
                return Err((key, format!("`{}` is not a band of this dataset ({})", c.band, band_names.join(", "))));
            };
            if out[b].is_some() {
                return Err((key, format!("band `{}` has two cameras", c.band)));
            }
            let camera = Camera { width, height, ..c.camera };
            for (name, f) in [("fl_x", camera.fx), ("fl_y", camera.fy)] {
                if let Some(why) = implausible_focal(f, width as f64, height as f64) {
                    return Err((format!("rig_cameras.cameras[{i}].{name}"), why));
                }
            }
            out[b] = Some(BandCamera { camera, rig_from_band: c.rig_from_band });
        }
        if let Some(b) = out.iter().position(Option::is_none) {
            return Err(("rig_cameras.cameras".into(), format!("band `{}` has no camera", band_names[b])));
        }
        Ok(RigCameras { cameras: out.into_iter().flatten().collect() })
    }
}

/// The camera-to-world of band camera `cam` on a frame whose pose is `c2w` (both in the dataset's world).
pub fn band_c2w(c2w: &Mat4, cam: &BandCamera) -> Mat4 {
    let mut out = [[0.0; 4]; 4];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..4).map(|k| c2w[i][k] * cam.rig_from_band[k][j]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_pose_composes_frame_and_rig() {
        // Frame camera 10 m up looking down (OpenGL: -z forward), band camera 5 cm to the camera's right.
        let c2w = [[1.0, 0.0, 0.0, 2.0], [0.0, -1.0, 0.0, 3.0], [0.0, 0.0, -1.0, 10.0], [0.0, 0.0, 0.0, 1.0]];
        let cam = BandCamera {
            camera: Camera {
                model: CameraModel::Pinhole,
                fx: 1.0,
                fy: 1.0,
                cx: 0.5,
                cy: 0.5,
                width: 1,
                height: 1,
                distortion: Distortion::default(),
            },
            rig_from_band: [[1.0, 0.0, 0.0, 0.05], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        };
        let m = band_c2w(&c2w, &cam);
        assert_eq!([m[0][3], m[1][3], m[2][3]], [2.05, 3.0, 10.0]);
        assert_eq!(m[1][1], -1.0);
        assert!(!cam.is_frame_camera(&cam.camera));
    }
}
