//! Agisoft Metashape camera exports (`File > Export > Export Cameras`, Agisoft XML), parsed with roxmltree:
//! - a camera's `<transform>` is its camera-to-chunk 4x4 (row-major; camera axes x right, y down, z forward, as
//!   OpenCV), in the coordinates of its `component_id`'s component when there is one;
//! - a component's and the chunk's `<transform>` (rotation 3x3, translation, scale) map local to outer
//!   coordinates as `x_outer = s R x_local + t` (one popular converter divides t by s: wrong);
//!   camera-to-world = chunk * component * camera, scale divided out of the rotation;
//! - the *adjusted* calibration of each sensor (`<calibration class="adjusted">`; the `initial` one is what the
//!   user typed in): f in pixels, cx/cy as offsets from the image centre, k1-k4, p1-p2, b1 (affinity: fx = f + b1)
//!   and b2 (skew, refused when non-zero); note Metashape's p1/p2 are OpenCV's p2/p1;
//! - disabled cameras (`enabled="false"` or `"0"`) and cameras without a transform (not aligned) are not posed;
//! - multi-camera systems (a multispectral rig loaded as one): a slave `<sensor master_id=...>` carries its offset
//!   (`<rotation>` slave-to-master, row-major; `<location>` the slave's centre in the master camera frame), and a
//!   slave `<camera master_id=...>` has no transform: it is posed as its master camera's transform times that
//!   offset. The location is taken in the chunk's internal units, like camera transforms, as the one open-source
//!   reader that handles rigs does (facebookresearch/EyefulTower `metashape_to_krt.py`); not checked against a
//!   real export;
//! - a georeferenced chunk (`<reference>` holding a geographic CRS) has its chunk transform map to ECEF (EPSG:4978):
//!   poses are projected into a projected CRS (`--crs`, default the cameras' WGS 84 UTM zone): centres exactly
//!   through [`crate::geo::Projector`], rotations turned with the grid at the cameras' mean position (meridian
//!   convergence included); heights are ellipsoidal. The CRS becomes the dataset's `crs`.

use std::collections::HashMap;
use std::path::Path;

use glam::{DMat3, DMat4, DVec3};

use super::error::PoseError;
use super::model::{PoseCamera, PoseModel, PosedImage};
use crate::geo::{Crs, Projector};

fn numbers(node: roxmltree::Node, path: &Path, at: &str) -> Result<Vec<f64>, PoseError> {
    node.text()
        .unwrap_or("")
        .split_whitespace()
        .map(|s| s.parse::<f64>().map_err(|_| PoseError::parse(path, at, format!("{s:?} is not a number"))))
        .collect()
}

fn child<'a>(node: roxmltree::Node<'a, 'a>, name: &str) -> Option<roxmltree::Node<'a, 'a>> {
    node.children().find(|c| c.is_element() && c.tag_name().name() == name)
}

/// The row-major 3x3 of a `<rotation>` child of `n` (identity when absent).
fn rotation_child(n: roxmltree::Node, path: &Path, at: &str) -> Result<DMat3, PoseError> {
    match child(n, "rotation") {
        Some(r) => {
            let v = numbers(r, path, at)?;
            if v.len() != 9 {
                return Err(PoseError::parse(path, at, "rotation needs 9 numbers"));
            }
            Ok(DMat3::from_cols_array(&[v[0], v[3], v[6], v[1], v[4], v[7], v[2], v[5], v[8]]))
        }
        None => Ok(DMat3::IDENTITY),
    }
}

/// The 3-vector of a `name` child of `n` (zero when absent).
fn vector_child(n: roxmltree::Node, name: &str, path: &Path, at: &str) -> Result<DVec3, PoseError> {
    match child(n, name) {
        Some(c) => {
            let v = numbers(c, path, at)?;
            if v.len() != 3 {
                return Err(PoseError::parse(path, at, format!("{name} needs 3 numbers")));
            }
            Ok(DVec3::new(v[0], v[1], v[2]))
        }
        None => Ok(DVec3::ZERO),
    }
}

/// The 4x4 `[m | t]`.
fn affine(m: DMat3, t: DVec3) -> DMat4 {
    DMat4::from_cols(m.x_axis.extend(0.0), m.y_axis.extend(0.0), m.z_axis.extend(0.0), t.extend(1.0))
}

/// `s R x + t` as a 4x4, from a `<transform>` with `<rotation>`, `<translation>`, `<scale>` (each optional).
fn similarity(t: roxmltree::Node, path: &Path, at: &str) -> Result<DMat4, PoseError> {
    let r = rotation_child(t, path, at)?;
    let tr = vector_child(t, "translation", path, at)?;
    let s = match child(t, "scale") {
        Some(n) => *numbers(n, path, at)?.first().ok_or_else(|| PoseError::parse(path, at, "empty scale"))?,
        None => 1.0,
    };
    Ok(affine(r * s, tr))
}

/// A slave sensor's offset in a multi-camera system: `<rotation>` (9 numbers, row-major, slave camera axes to the
/// master's) and `<location>` (the slave's centre in the master camera's frame) as the slave-to-master 4x4.
fn slave_offset(s: roxmltree::Node, path: &Path, at: &str) -> Result<DMat4, PoseError> {
    Ok(affine(rotation_child(s, path, at)?, vector_child(s, "location", path, at)?))
}

fn sensor_camera(s: roxmltree::Node, path: &Path) -> Result<(String, PoseCamera), PoseError> {
    let id = s.attribute("id").unwrap_or("?").to_string();
    let at = format!("sensor {id}");
    let cal = s
        .children()
        .filter(|c| c.is_element() && c.tag_name().name() == "calibration")
        .find(|c| c.attribute("class") == Some("adjusted"))
        .or_else(|| s.children().find(|c| c.is_element() && c.tag_name().name() == "calibration"))
        .ok_or_else(|| PoseError::parse(path, &at, "no <calibration>"))?;
    let res = child(cal, "resolution")
        .or_else(|| child(s, "resolution"))
        .ok_or_else(|| PoseError::parse(path, &at, "no <resolution>"))?;
    let dim = |k: &str| -> Result<f64, PoseError> {
        res.attribute(k)
            .and_then(|v| v.parse::<f64>().ok())
            .ok_or_else(|| PoseError::parse(path, &at, format!("resolution without {k}")))
    };
    let (w, h) = (dim("width")?, dim("height")?);
    let get = |k: &str| -> Result<f64, PoseError> {
        match child(cal, k) {
            Some(n) => numbers(n, path, &at)?
                .first()
                .copied()
                .ok_or_else(|| PoseError::parse(path, &at, format!("empty <{k}>"))),
            None => Ok(0.0),
        }
    };
    let f = get("f")?;
    if f <= 0.0 {
        return Err(PoseError::parse(path, &at, "calibration without a positive <f>"));
    }
    if get("b2")? != 0.0 {
        return Err(PoseError::parse(path, &at, "skew b2 is not zero: msnerf's cameras have no skew"));
    }
    let typ = cal.attribute("type").unwrap_or("frame");
    let (model, mut keys) = match typ {
        "frame" => (
            "OPENCV",
            vec![("k1", get("k1")?), ("k2", get("k2")?), ("k3", get("k3")?), ("p1", get("p2")?), ("p2", get("p1")?)],
        ),
        "fisheye" => {
            ("OPENCV_FISHEYE", vec![("k1", get("k1")?), ("k2", get("k2")?), ("k3", get("k3")?), ("k4", get("k4")?)])
        }
        other => {
            return Err(PoseError::parse(
                path,
                &at,
                format!("calibration type {other} has no msnerf equivalent (frame, fisheye)"),
            ))
        }
    };
    if typ == "frame" && get("k4")? != 0.0 {
        return Err(PoseError::parse(path, &at, "k4 is not zero: msnerf's OPENCV model has k1-k3"));
    }
    keys.extend([("fl_x", f + get("b1")?), ("fl_y", f), ("cx", w / 2.0 + get("cx")?), ("cy", h / 2.0 + get("cy")?)]);
    Ok((id, PoseCamera { width: w as u64, height: h as u64, model, keys }))
}

/// Reads a Metashape camera XML; a georeferenced chunk's poses come out in `crs` (default: the WGS 84 UTM zone of
/// the cameras).
pub fn read_cameras_xml(path: &Path, crs: Option<&Crs>) -> Result<PoseModel, PoseError> {
    let text = std::fs::read_to_string(path).map_err(PoseError::io(path))?;
    let doc = roxmltree::Document::parse(&text).map_err(|e| PoseError::parse(path, "XML", e.to_string()))?;
    let chunk = doc
        .descendants()
        .find(|n| n.is_element() && n.tag_name().name() == "chunk")
        .ok_or_else(|| PoseError::parse(path, "document", "no <chunk>"))?;
    let mut sensors = HashMap::new();
    let mut slave_offsets: HashMap<String, DMat4> = HashMap::new();
    for s in chunk.descendants().filter(|n| n.is_element() && n.tag_name().name() == "sensor") {
        let (id, cam) = sensor_camera(s, path)?;
        if s.attribute("master_id").is_some_and(|m| m != id) {
            slave_offsets.insert(id.clone(), slave_offset(s, path, &format!("sensor {id}"))?);
        }
        sensors.insert(id, cam);
    }
    let mut components = HashMap::new();
    for c in chunk.descendants().filter(|n| n.is_element() && n.tag_name().name() == "component") {
        let id = c.attribute("id").unwrap_or("?").to_string();
        let m = match child(c, "transform") {
            Some(t) => similarity(t, path, &format!("component {id}"))?,
            None => DMat4::IDENTITY,
        };
        components.insert(id, m);
    }
    let mut notes = Vec::new();
    let chunk_m = match child(chunk, "transform") {
        Some(t) => similarity(t, path, "chunk transform")?,
        None => DMat4::IDENTITY,
    };
    let has_reference =
        child(chunk, "reference").and_then(|r| r.text()).is_some_and(|t| t.trim_start().starts_with("GEOGCS"));
    // The chunk transform is what maps chunk coordinates to ECEF: without it a reference says nothing about them.
    let geocentric = has_reference && child(chunk, "transform").is_some();
    if has_reference && !geocentric {
        notes.push(
            "the chunk has a geographic reference but no <transform>: it was never georeferenced (no markers or \
             camera references used), so the poses stay in the chunk's local frame, without a crs"
                .to_string(),
        );
    }
    let mut images = Vec::new();
    let mut raw: Vec<(String, DMat4, PoseCamera)> = Vec::new();
    let cameras: Vec<_> = chunk.descendants().filter(|n| n.is_element() && n.tag_name().name() == "camera").collect();
    // Camera-to-chunk of every camera with a transform (masters of multi-camera systems among them).
    let mut local_of: HashMap<String, DMat4> = HashMap::new();
    for cam in &cameras {
        let at = format!("camera {}", cam.attribute("label").unwrap_or(""));
        if let Some(t) = child(*cam, "transform") {
            let v = numbers(t, path, &at)?;
            if v.len() != 16 {
                return Err(PoseError::parse(path, &at, "camera transform needs 16 numbers"));
            }
            local_of.insert(cam.attribute("id").unwrap_or("").to_string(), DMat4::from_cols_slice(&v).transpose());
        }
    }
    let mut slaves = 0usize;
    for (k, cam) in cameras.iter().enumerate() {
        let cam = *cam;
        let label = cam.attribute("label").unwrap_or("").to_string();
        let at = format!("camera {label}");
        if matches!(cam.attribute("enabled"), Some("false") | Some("0")) {
            continue;
        }
        let sid = cam.attribute("sensor_id").unwrap_or("");
        let own = local_of.get(cam.attribute("id").unwrap_or("")).copied();
        // A slave camera of a multi-camera system has no transform: its master's, times its sensor's offset.
        let local = match (own, cam.attribute("master_id"), slave_offsets.get(sid)) {
            (Some(l), _, _) => l,
            (None, Some(master), Some(offset)) => match local_of.get(master) {
                Some(m) => {
                    slaves += 1;
                    *m * *offset
                }
                None => continue,
            },
            _ => continue,
        };
        let comp = match cam.attribute("component_id") {
            Some(c) => *components
                .get(c)
                .ok_or_else(|| PoseError::parse(path, &at, format!("component {c} is not in <components>")))?,
            None => DMat4::IDENTITY,
        };
        let sensor = sensors
            .get(sid)
            .cloned()
            .ok_or_else(|| PoseError::parse(path, &at, format!("sensor {sid:?} is not in <sensors>")))?;
        let _ = k;
        raw.push((label, chunk_m * comp * local, sensor));
    }
    if slaves > 0 {
        notes.push(format!(
            "multi-camera system: {slaves} slave camera(s) posed from their master camera and their sensor's offset \
             (<rotation> slave-to-master, <location> in the chunk's units like camera transforms)"
        ));
    }
    // Georeferenced: ECEF -> the projected CRS asked for, or the cameras' UTM zone. Positions are projected
    // exactly; rotations turn with the grid at the cameras' mean position (its Jacobian, made orthonormal).
    let projected = if geocentric && !raw.is_empty() {
        let mean = raw.iter().map(|r| r.1.w_axis.truncate()).sum::<DVec3>() / raw.len() as f64;
        let crs = match crs {
            Some(c) => c.clone(),
            None => {
                let (lat, lon) = geodetic_of(mean);
                Crs::utm_for(lat, lon).map_err(|e| PoseError::parse(path, "chunk reference", e.to_string()))?
            }
        };
        let proj =
            Projector::new(&crs).map_err(|e| PoseError::Option { key: "--crs".into(), reason: e.to_string() })?;
        let r = proj
            .ecef_rotation(mean.to_array(), 1.0)
            .map_err(|e| PoseError::parse(path, "chunk reference", e.to_string()))?;
        let r = DMat3::from_cols_array_2d(&r).transpose(); // rows in the array
        Some((proj, r))
    } else {
        None
    };
    for (k, (label, m, camera)) in raw.into_iter().enumerate() {
        let r3 = DMat3::from_mat4(m);
        let s = r3.determinant().cbrt();
        let mut rot = r3 * (1.0 / s);
        let mut centre = m.w_axis.truncate();
        if let Some((proj, r)) = &projected {
            rot = *r * rot;
            centre = DVec3::from_array(
                proj.from_ecef(centre.to_array())
                    .map_err(|e| PoseError::parse(path, format!("camera {label}"), e.to_string()))?,
            );
        }
        // Column j of the rotation is camera axis j in the world; OpenCV -> OpenGL negates y and z.
        let c2w: [[f64; 4]; 4] = std::array::from_fn(|i| {
            if i == 3 {
                return [0.0, 0.0, 0.0, 1.0];
            }
            std::array::from_fn(|j| match j {
                3 => centre[i],
                0 => rot.col(0)[i],
                _ => -rot.col(j)[i],
            })
        });
        images.push(PosedImage { id: k as u64, name: label, c2w, camera });
    }
    let crs = projected.map(|(p, _)| p.crs);
    Ok(PoseModel { tool: "metashape", images, points: Vec::new(), crs, notes })
}

/// Geodetic latitude and longitude (degrees) of an ECEF position (Bowring's iteration on WGS84, far below a
/// millimetre); used to pick the UTM zone.
fn geodetic_of(p: DVec3) -> (f64, f64) {
    let lon = p.y.atan2(p.x);
    let r = (p.x * p.x + p.y * p.y).sqrt();
    let (a, f) = (6_378_137.0, 1.0 / 298.257_223_563);
    let e2 = f * (2.0 - f);
    let mut lat = (p.z / (r * (1.0 - e2))).atan();
    for _ in 0..5 {
        let n = a / (1.0 - e2 * lat.sin().powi(2)).sqrt();
        let h = r / lat.cos() - n;
        lat = (p.z / (r * (1.0 - e2 * n / (n + h)))).atan();
    }
    (lat.to_degrees(), lon.to_degrees())
}
