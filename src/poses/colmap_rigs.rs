//! COLMAP >= 3.12 rigs and frames (`rigs.txt|bin`, `frames.txt|bin` beside cameras and images): a rig is a set of
//! sensors (cameras) with a reference sensor and, for the others, `sensor_from_rig`; a frame is one capture of a
//! rig with its `rig_from_world` and the images (data ids) it holds. COLMAP reads an image's pose as
//! `cam_from_world = cam_from_rig * rig_from_world` (identity `cam_from_rig` for the reference sensor) and
//! discards the pose in `images.*` when these files are present; [`compose`] does the same, and measures how far
//! the images file's own pose was from it. Layouts (little-endian; colmap/colmap `reconstruction_io_text.cc`,
//! `reconstruction_io_binary.cc`, tag 3.12.0):
//! - `rigs.txt`: `RIG_ID NUM_SENSORS REF_TYPE REF_ID` then per other sensor `TYPE ID HAS_POSE [QW QX QY QZ TX TY TZ]`;
//!   `rigs.bin`: u64 count; per rig u32 id, u32 num_sensors, (if > 0) i32 ref type, u32 ref id, then per other
//!   sensor i32 type, u32 id, u8 has_pose, 7 f64 when it has one;
//! - `frames.txt`: `FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS` then `TYPE SENSOR_ID DATA_ID` triples;
//!   `frames.bin`: u64 count; per frame u32 id, u32 rig id, 7 f64, u32 n, n x (i32 type, u32 sensor id, u64 data id).
//!
//! Sensor types: CAMERA = 0, IMU = 1 (text: the names). For a camera, sensor id = camera id, data id = image id.

use std::collections::HashMap;
use std::path::Path;

use super::colmap::{data_lines, num, read_file, ColmapModel, Reader};
use super::error::PoseError;

/// A pose as COLMAP stores it: quaternion (w, x, y, z; Hamilton) and translation, mapping `from` to `to`.
pub type Pose = ([f64; 4], [f64; 3]);

/// A sensor of a rig: (type, id) and its `sensor_from_rig` (None for the reference sensor, or unknown).
#[derive(Debug, Clone, PartialEq)]
pub struct RigSensor {
    pub sensor_type: i32,
    pub id: u32,
    pub sensor_from_rig: Option<Pose>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    pub id: u32,
    /// The reference sensor first (its pose is the identity), then the others.
    pub sensors: Vec<RigSensor>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub id: u32,
    pub rig_id: u32,
    pub rig_from_world: Pose,
    /// (sensor type, sensor id, data id).
    pub data: Vec<(i32, u32, u64)>,
}

/// The rigs and frames of a model, with how far the images file's poses were from the composed ones.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RigModel {
    pub rigs: Vec<Rig>,
    pub frames: Vec<Frame>,
    /// Largest difference between an image's pose in `images.*` and `cam_from_rig * rig_from_world`: rotation in
    /// degrees and camera centre in model units.
    pub max_rotation_diff_deg: f64,
    pub max_centre_diff: f64,
}

const CAMERA: i32 = 0;
const IMU: i32 = 1;

fn sensor_type(path: &Path, line: usize, s: Option<&str>) -> Result<i32, PoseError> {
    match s {
        Some("CAMERA") => Ok(CAMERA),
        Some("IMU") => Ok(IMU),
        other => Err(PoseError::parse(
            path,
            format!("line {line}"),
            format!("sensor type {other:?} is neither CAMERA nor IMU"),
        )),
    }
}

fn read_text(dir: &Path) -> Result<(Vec<Rig>, Vec<Frame>), PoseError> {
    let p = dir.join("rigs.txt");
    let mut rigs = Vec::new();
    for (ln, l) in data_lines(&p)? {
        let mut it = l.split_whitespace();
        let id: u32 = num(&p, ln, "RIG_ID", it.next())?;
        let n: usize = num(&p, ln, "NUM_SENSORS", it.next())?;
        let mut sensors = Vec::with_capacity(n);
        if n > 0 {
            let t = sensor_type(&p, ln, it.next())?;
            sensors.push(RigSensor {
                sensor_type: t,
                id: num(&p, ln, "REF_SENSOR_ID", it.next())?,
                sensor_from_rig: None,
            });
        }
        for _ in 1..n {
            let t = sensor_type(&p, ln, it.next())?;
            let sid: u32 = num(&p, ln, "SENSOR_ID", it.next())?;
            let has: u8 = num(&p, ln, "HAS_POSE", it.next())?;
            let pose = if has == 1 {
                let v: Vec<f64> =
                    (0..7).map(|_| num(&p, ln, "sensor_from_rig", it.next())).collect::<Result<_, _>>()?;
                Some(([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]]))
            } else {
                None
            };
            sensors.push(RigSensor { sensor_type: t, id: sid, sensor_from_rig: pose });
        }
        rigs.push(Rig { id, sensors });
    }
    let p = dir.join("frames.txt");
    let mut frames = Vec::new();
    for (ln, l) in data_lines(&p)? {
        let mut it = l.split_whitespace();
        let id: u32 = num(&p, ln, "FRAME_ID", it.next())?;
        let rig_id: u32 = num(&p, ln, "RIG_ID", it.next())?;
        let v: Vec<f64> = (0..7).map(|_| num(&p, ln, "rig_from_world", it.next())).collect::<Result<_, _>>()?;
        let n: usize = num(&p, ln, "NUM_DATA_IDS", it.next())?;
        let mut data = Vec::with_capacity(n);
        for _ in 0..n {
            let t = sensor_type(&p, ln, it.next())?;
            data.push((t, num(&p, ln, "SENSOR_ID", it.next())?, num(&p, ln, "DATA_ID", it.next())?));
        }
        frames.push(Frame { id, rig_id, rig_from_world: ([v[0], v[1], v[2], v[3]], [v[4], v[5], v[6]]), data });
    }
    Ok((rigs, frames))
}

fn pose(r: &mut Reader) -> Result<Pose, PoseError> {
    Ok(([r.f64()?, r.f64()?, r.f64()?, r.f64()?], [r.f64()?, r.f64()?, r.f64()?]))
}

fn read_binary(dir: &Path) -> Result<(Vec<Rig>, Vec<Frame>), PoseError> {
    let p = dir.join("rigs.bin");
    let bytes = read_file(&p)?;
    let mut r = Reader { path: &p, b: &bytes, at: 0, record: "header".into() };
    let n = r.count(8)?;
    let mut rigs = Vec::with_capacity(n);
    for k in 0..n {
        r.record = format!("rig {k}");
        let id = r.i32()? as u32;
        let ns = r.i32()? as u32 as usize;
        let mut sensors = Vec::new();
        if ns > 0 {
            sensors.push(RigSensor { sensor_type: r.i32()?, id: r.i32()? as u32, sensor_from_rig: None });
        }
        for _ in 1..ns {
            let (t, sid, has) = (r.i32()?, r.i32()? as u32, r.u8()?);
            let pose = if has == 1 { Some(pose(&mut r)?) } else { None };
            sensors.push(RigSensor { sensor_type: t, id: sid, sensor_from_rig: pose });
        }
        rigs.push(Rig { id, sensors });
    }
    let p = dir.join("frames.bin");
    let bytes = read_file(&p)?;
    let mut r = Reader { path: &p, b: &bytes, at: 0, record: "header".into() };
    let n = r.count(68)?;
    let mut frames = Vec::with_capacity(n);
    for k in 0..n {
        r.record = format!("frame {k}");
        let (id, rig_id) = (r.i32()? as u32, r.i32()? as u32);
        let rig_from_world = pose(&mut r)?;
        let nd = r.i32()? as u32 as usize;
        let mut data = Vec::with_capacity(nd.min(1 << 16));
        for _ in 0..nd {
            data.push((r.i32()?, r.i32()? as u32, r.u64()?));
        }
        frames.push(Frame { id, rig_id, rig_from_world, data });
    }
    Ok((rigs, frames))
}

/// Hamilton product `a * b` (w, x, y, z).
fn qmul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// `v` rotated by the unit quaternion `q`.
fn qrot(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let p = qmul(qmul(q, [0.0, v[0], v[1], v[2]]), [q[0], -q[1], -q[2], -q[3]]);
    [p[1], p[2], p[3]]
}

fn normalized(q: [f64; 4]) -> [f64; 4] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / n)
}

/// `a * b` of two poses (apply b, then a).
fn compose_poses(a: Pose, b: Pose) -> Pose {
    let q = normalized(qmul(normalized(a.0), normalized(b.0)));
    let r = qrot(normalized(a.0), b.1);
    (q, [r[0] + a.1[0], r[1] + a.1[1], r[2] + a.1[2]])
}

/// Camera centre of a world-to-camera pose: `-R^T t`.
fn centre(p: Pose) -> [f64; 3] {
    let q = normalized(p.0);
    qrot([q[0], -q[1], -q[2], -q[3]], p.1).map(|v| -v)
}

/// Reads the rigs and frames in `dir` when both are there (text or `binary`), and sets every image's pose to
/// `cam_from_rig * rig_from_world` as COLMAP does. Errors name the file, and an image that no frame holds.
pub fn compose(dir: &Path, m: &mut ColmapModel, binary: bool) -> Result<(), PoseError> {
    let (r, f) = if binary { ("rigs.bin", "frames.bin") } else { ("rigs.txt", "frames.txt") };
    match (dir.join(r).is_file(), dir.join(f).is_file()) {
        (false, false) => return Ok(()),
        (true, true) => {}
        (has_rigs, _) => {
            let (have, lack) = if has_rigs { (r, f) } else { (f, r) };
            return Err(PoseError::parse(
                &dir.join(have),
                "model",
                format!("{have} without {lack}: COLMAP needs both"),
            ));
        }
    }
    let (rigs, frames) = if binary { read_binary(dir)? } else { read_text(dir)? };
    let by_rig: HashMap<u32, &Rig> = rigs.iter().map(|r| (r.id, r)).collect();
    let mut cam_from_world: HashMap<u64, Pose> = HashMap::new();
    let fpath = dir.join(f);
    for fr in &frames {
        let rig = by_rig.get(&fr.rig_id).ok_or_else(|| {
            PoseError::parse(&fpath, format!("frame {}", fr.id), format!("rig {} is not in {r}", fr.rig_id))
        })?;
        for &(t, sid, data) in fr.data.iter().filter(|d| d.0 == CAMERA) {
            let pos = rig.sensors.iter().position(|s| s.sensor_type == t && s.id == sid).ok_or_else(|| {
                PoseError::parse(
                    &fpath,
                    format!("frame {}", fr.id),
                    format!("camera {sid} is not a sensor of rig {}", rig.id),
                )
            })?;
            let pose = match (pos, rig.sensors[pos].sensor_from_rig) {
                (0, _) => fr.rig_from_world,
                (_, Some(s)) => compose_poses(s, fr.rig_from_world),
                (_, None) => {
                    return Err(PoseError::parse(
                        &dir.join(r),
                        format!("rig {}", rig.id),
                        format!("camera {sid} has no sensor_from_rig pose, so image {data} cannot be placed"),
                    ))
                }
            };
            cam_from_world.insert(data, pose);
        }
    }
    let (mut dr, mut dc) = (0.0f64, 0.0f64);
    for im in &mut m.images {
        let p = *cam_from_world.get(&u64::from(im.id)).ok_or_else(|| {
            PoseError::parse(&fpath, format!("image {} ({})", im.id, im.name), "no frame holds this image")
        })?;
        let d = qmul(normalized(p.0), normalized([im.q[0], -im.q[1], -im.q[2], -im.q[3]]));
        dr = dr.max(2.0 * d[0].abs().min(1.0).acos().to_degrees());
        let (a, b) = (centre(p), centre((im.q, im.t)));
        dc = dc.max(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt());
        (im.q, im.t) = p;
    }
    m.rigs = Some(RigModel { rigs, frames, max_rotation_diff_deg: dr, max_centre_diff: dc });
    Ok(())
}
