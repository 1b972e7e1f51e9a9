//! COLMAP sparse models, text (`cameras.txt`, `images.txt`, `points3D.txt`) and binary (`.bin`), as COLMAP's
//! `src/colmap/scene/reconstruction_io` writes them (https://colmap.github.io/format.html):
//! - cameras: id, model, width, height, params (model order below);
//! - images: id, world-to-camera rotation as a unit quaternion (qw, qx, qy, qz; Hamilton), translation (tx, ty, tz),
//!   camera id, name, then the 2-D points (x, y, point3D id or -1); camera axes are OpenCV's (x right, y down,
//!   z forward), pixel centres at (i + 0.5, j + 0.5) as in msnerf's datasets;
//! - points3D: id, x, y, z, r, g, b, reprojection error, track of (image id, 2-D point index).
//!
//! Binary: little-endian; counts are u64, ids i32 (images, cameras) and u64 (points), names NUL-terminated.

use std::collections::BTreeMap;
use std::path::Path;

use super::error::PoseError;
use super::model::{c2w_from_w2c_opencv, PoseCamera, PoseModel, PosePoint, PosedImage};

/// A COLMAP camera model with its parameters in COLMAP's order.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: String,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

/// One registered image.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation (qw, qx, qy, qz) and translation.
    pub q: [f64; 4],
    pub t: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// The image's 2-D points (pixels, the image's corner at 0), indexed as the points' tracks index them.
    pub points2d: Vec<[f64; 2]>,
}

/// One 3-D point with its track (image ids, and each image's 2-D point index beside it).
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    pub error: f64,
    pub images: Vec<u32>,
    /// Index of the observation in its image's `points2d`, one per entry of `images`.
    pub point2d: Vec<u32>,
}

/// A whole sparse model.
#[derive(Debug, Clone, Default)]
pub struct ColmapModel {
    pub cameras: BTreeMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
    /// COLMAP >= 3.12 rigs and frames (`rigs.*`, `frames.*`), when the model has them.
    pub rigs: Option<super::colmap_rigs::RigModel>,
}

/// (name, model id, number of parameters) of the models COLMAP defines.
pub const MODELS: [(&str, i32, usize); 11] = [
    ("SIMPLE_PINHOLE", 0, 3),
    ("PINHOLE", 1, 4),
    ("SIMPLE_RADIAL", 2, 4),
    ("RADIAL", 3, 5),
    ("OPENCV", 4, 8),
    ("OPENCV_FISHEYE", 5, 8),
    ("FULL_OPENCV", 6, 12),
    ("FOV", 7, 5),
    ("SIMPLE_RADIAL_FISHEYE", 8, 4),
    ("RADIAL_FISHEYE", 9, 5),
    ("THIN_PRISM_FISHEYE", 10, 12),
];

fn param_count(model: &str) -> Option<usize> {
    MODELS.iter().find(|m| m.0 == model).map(|m| m.2)
}

/// Reads the model in `dir`: the binary files when `cameras.bin` is there, else the text files.
pub fn read_model(dir: &Path) -> Result<ColmapModel, PoseError> {
    if dir.join("cameras.bin").is_file() {
        read_binary(dir)
    } else if dir.join("cameras.txt").is_file() {
        read_text(dir)
    } else {
        Err(PoseError::Dataset {
            path: dir.to_path_buf(),
            reason:
                "no COLMAP model here (cameras.bin/images.bin/points3D.bin or cameras.txt/images.txt/points3D.txt; \
                     usually sparse/0)"
                    .into(),
        })
    }
}

pub(super) fn data_lines(path: &Path) -> Result<Vec<(usize, String)>, PoseError> {
    let text = std::fs::read_to_string(path).map_err(PoseError::io(path))?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect())
}

pub(super) fn num<T: std::str::FromStr>(path: &Path, line: usize, what: &str, s: Option<&str>) -> Result<T, PoseError> {
    let s = s.ok_or_else(|| PoseError::parse(path, format!("line {line}"), format!("missing {what}")))?;
    s.parse::<T>().map_err(|_| PoseError::parse(path, format!("line {line}"), format!("{what}: {s:?} is not a number")))
}

/// Reads `cameras.txt`, `images.txt` and `points3D.txt` (the last may be absent).
pub fn read_text(dir: &Path) -> Result<ColmapModel, PoseError> {
    let mut m = ColmapModel::default();
    let p = dir.join("cameras.txt");
    for (ln, l) in data_lines(&p)? {
        let mut it = l.split_whitespace();
        let id: u32 = num(&p, ln, "CAMERA_ID", it.next())?;
        let model = it.next().ok_or_else(|| PoseError::parse(&p, format!("line {ln}"), "missing MODEL"))?.to_string();
        let width: u64 = num(&p, ln, "WIDTH", it.next())?;
        let height: u64 = num(&p, ln, "HEIGHT", it.next())?;
        let params: Vec<f64> = it.map(|s| num(&p, ln, "PARAMS", Some(s))).collect::<Result<_, _>>()?;
        match param_count(&model) {
            None => return Err(PoseError::parse(&p, format!("line {ln}"), format!("unknown camera model {model}"))),
            Some(n) if n != params.len() => {
                return Err(PoseError::parse(
                    &p,
                    format!("line {ln}"),
                    format!("{model} takes {n} parameters, {} given", params.len()),
                ))
            }
            _ => {}
        }
        m.cameras.insert(id, ColmapCamera { id, model, width, height, params });
    }
    let p = dir.join("images.txt");
    // Image lines alternate with their 2-D point lines; a registered image with no points has an empty second line,
    // which `data_lines` drops, so pair lines by their content: an image line has 10+ fields and a name.
    let text = std::fs::read_to_string(&p).map_err(PoseError::io(&p))?;
    let raw: Vec<&str> = text.lines().collect();
    let mut i = 0;
    while i < raw.len() {
        let l = raw[i].trim();
        if l.is_empty() || l.starts_with('#') {
            i += 1;
            continue;
        }
        let ln = i + 1;
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() < 10 {
            return Err(PoseError::parse(
                &p,
                format!("line {ln}"),
                "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
            ));
        }
        let id: u32 = num(&p, ln, "IMAGE_ID", Some(f[0]))?;
        let q = [
            num(&p, ln, "QW", Some(f[1]))?,
            num(&p, ln, "QX", Some(f[2]))?,
            num(&p, ln, "QY", Some(f[3]))?,
            num(&p, ln, "QZ", Some(f[4]))?,
        ];
        let t = [num(&p, ln, "TX", Some(f[5]))?, num(&p, ln, "TY", Some(f[6]))?, num(&p, ln, "TZ", Some(f[7]))?];
        let camera_id: u32 = num(&p, ln, "CAMERA_ID", Some(f[8]))?;
        // Names may contain spaces: everything after the camera id.
        let name = f[9..].join(" ");
        // The POINTS2D line (possibly empty): X Y POINT3D_ID triplets.
        let pl = raw.get(i + 1).map_or("", |l| l.trim());
        let v: Vec<&str> = pl.split_whitespace().collect();
        if v.len() % 3 != 0 {
            return Err(PoseError::parse(&p, format!("line {}", ln + 1), "POINTS2D: expected X Y POINT3D_ID triplets"));
        }
        let points2d = v
            .chunks(3)
            .map(|c| Ok([num(&p, ln + 1, "X", Some(c[0]))?, num(&p, ln + 1, "Y", Some(c[1]))?]))
            .collect::<Result<_, PoseError>>()?;
        m.images.push(ColmapImage { id, q, t, camera_id, name, points2d });
        i += 2;
    }
    let p = dir.join("points3D.txt");
    if p.is_file() {
        for (ln, l) in data_lines(&p)? {
            let f: Vec<&str> = l.split_whitespace().collect();
            if f.len() < 8 {
                return Err(PoseError::parse(
                    &p,
                    format!("line {ln}"),
                    "expected POINT3D_ID X Y Z R G B ERROR TRACK[]",
                ));
            }
            let xyz = [num(&p, ln, "X", Some(f[1]))?, num(&p, ln, "Y", Some(f[2]))?, num(&p, ln, "Z", Some(f[3]))?];
            let rgb = [num(&p, ln, "R", Some(f[4]))?, num(&p, ln, "G", Some(f[5]))?, num(&p, ln, "B", Some(f[6]))?];
            let images =
                f[8..].chunks(2).map(|c| num(&p, ln, "IMAGE_ID", c.first().copied())).collect::<Result<_, _>>()?;
            let point2d =
                f[8..].chunks(2).map(|c| num(&p, ln, "POINT2D_IDX", c.get(1).copied())).collect::<Result<_, _>>()?;
            m.points.push(ColmapPoint {
                id: num(&p, ln, "POINT3D_ID", Some(f[0]))?,
                xyz,
                rgb,
                error: num(&p, ln, "ERROR", Some(f[7]))?,
                images,
                point2d,
            });
        }
    }
    super::colmap_rigs::compose(dir, &mut m, false)?;
    Ok(m)
}

pub(super) struct Reader<'a> {
    pub(super) path: &'a Path,
    pub(super) b: &'a [u8],
    pub(super) at: usize,
    pub(super) record: String,
}

impl Reader<'_> {
    pub(super) fn take(&mut self, n: usize) -> Result<&[u8], PoseError> {
        if self.at + n > self.b.len() {
            return Err(PoseError::parse(self.path, format!("byte {} ({})", self.at, self.record), "file ends early"));
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    pub(super) fn u64(&mut self) -> Result<u64, PoseError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    pub(super) fn i64(&mut self) -> Result<i64, PoseError> {
        Ok(i64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    pub(super) fn i32(&mut self) -> Result<i32, PoseError> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    pub(super) fn f64(&mut self) -> Result<f64, PoseError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    pub(super) fn u8(&mut self) -> Result<u8, PoseError> {
        Ok(self.take(1)?[0])
    }
    pub(super) fn name(&mut self) -> Result<String, PoseError> {
        let end = self.b[self.at..].iter().position(|&c| c == 0).ok_or_else(|| {
            PoseError::parse(self.path, format!("byte {} ({})", self.at, self.record), "image name not terminated")
        })?;
        let s = String::from_utf8_lossy(&self.b[self.at..self.at + end]).into_owned();
        self.at += end + 1;
        Ok(s)
    }
    /// A count that cannot exceed what is left of the file (`each` bytes per item at least).
    pub(super) fn count(&mut self, each: usize) -> Result<usize, PoseError> {
        let n = self.u64()?;
        if n as u128 * each as u128 > (self.b.len() - self.at) as u128 {
            return Err(PoseError::parse(
                self.path,
                format!("byte {} ({})", self.at, self.record),
                format!("count {n} larger than the file"),
            ));
        }
        Ok(n as usize)
    }
}

pub(super) fn read_file(path: &Path) -> Result<Vec<u8>, PoseError> {
    std::fs::read(path).map_err(PoseError::io(path))
}

/// Reads `cameras.bin`, `images.bin` and `points3D.bin` (the last may be absent).
pub fn read_binary(dir: &Path) -> Result<ColmapModel, PoseError> {
    let mut m = ColmapModel::default();
    let p = dir.join("cameras.bin");
    let bytes = read_file(&p)?;
    let mut r = Reader { path: &p, b: &bytes, at: 0, record: "header".into() };
    let n = r.count(24)?;
    for k in 0..n {
        r.record = format!("camera {k}");
        let id = r.i32()? as u32;
        let model_id = r.i32()?;
        let (name, _, np) = *MODELS.iter().find(|m| m.1 == model_id).ok_or_else(|| {
            PoseError::parse(&p, format!("camera {k}"), format!("unknown camera model id {model_id}"))
        })?;
        let width = r.u64()?;
        let height = r.u64()?;
        let params = (0..np).map(|_| r.f64()).collect::<Result<_, _>>()?;
        m.cameras.insert(id, ColmapCamera { id, model: name.into(), width, height, params });
    }
    let p = dir.join("images.bin");
    let bytes = read_file(&p)?;
    let mut r = Reader { path: &p, b: &bytes, at: 0, record: "header".into() };
    let n = r.count(64)?;
    for k in 0..n {
        r.record = format!("image {k}");
        let id = r.i32()? as u32;
        let q = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
        let t = [r.f64()?, r.f64()?, r.f64()?];
        let camera_id = r.i32()? as u32;
        let name = r.name()?;
        let np = r.count(24)?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            points2d.push([r.f64()?, r.f64()?]);
            r.i64()?;
        }
        m.images.push(ColmapImage { id, q, t, camera_id, name, points2d });
    }
    let p = dir.join("points3D.bin");
    if p.is_file() {
        let bytes = read_file(&p)?;
        let mut r = Reader { path: &p, b: &bytes, at: 0, record: "header".into() };
        let n = r.count(43)?;
        for k in 0..n {
            r.record = format!("point {k}");
            let id = r.u64()?;
            let xyz = [r.f64()?, r.f64()?, r.f64()?];
            let rgb = [r.u8()?, r.u8()?, r.u8()?];
            let error = r.f64()?;
            let tl = r.count(8)?;
            let mut images = Vec::with_capacity(tl);
            let mut point2d = Vec::with_capacity(tl);
            for _ in 0..tl {
                images.push(r.i32()? as u32);
                point2d.push(r.i32()? as u32);
            }
            m.points.push(ColmapPoint { id, xyz, rgb, error, images, point2d });
        }
    }
    super::colmap_rigs::compose(dir, &mut m, true)?;
    Ok(m)
}

/// The rotation matrix of COLMAP's world-to-camera quaternion (qw, qx, qy, qz; Hamilton, as Eigen's).
pub fn quaternion_matrix(q: [f64; 4]) -> Result<[[f64; 3]; 3], String> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n.is_finite() && (n - 1.0).abs() < 1e-3) {
        return Err(format!("quaternion {q:?} is not a unit quaternion (norm {n})"));
    }
    let [w, x, y, z] = q.map(|v| v / n);
    Ok([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ])
}

/// msnerf's camera for a COLMAP camera: pixel centres at (i + 0.5, j + 0.5) in both, so cx, cy are copied.
fn camera(c: &ColmapCamera, path: &Path, image: &str) -> Result<PoseCamera, PoseError> {
    let p = &c.params;
    let (model, keys): (&'static str, Vec<(&'static str, f64)>) = match c.model.as_str() {
        "SIMPLE_PINHOLE" => ("PINHOLE", vec![("fl_x", p[0]), ("fl_y", p[0]), ("cx", p[1]), ("cy", p[2])]),
        "PINHOLE" => ("PINHOLE", vec![("fl_x", p[0]), ("fl_y", p[1]), ("cx", p[2]), ("cy", p[3])]),
        "SIMPLE_RADIAL" => ("OPENCV", vec![("fl_x", p[0]), ("fl_y", p[0]), ("cx", p[1]), ("cy", p[2]), ("k1", p[3])]),
        "RADIAL" => {
            ("OPENCV", vec![("fl_x", p[0]), ("fl_y", p[0]), ("cx", p[1]), ("cy", p[2]), ("k1", p[3]), ("k2", p[4])])
        }
        "OPENCV" => (
            "OPENCV",
            vec![
                ("fl_x", p[0]),
                ("fl_y", p[1]),
                ("cx", p[2]),
                ("cy", p[3]),
                ("k1", p[4]),
                ("k2", p[5]),
                ("p1", p[6]),
                ("p2", p[7]),
            ],
        ),
        "OPENCV_FISHEYE" => (
            "OPENCV_FISHEYE",
            vec![
                ("fl_x", p[0]),
                ("fl_y", p[1]),
                ("cx", p[2]),
                ("cy", p[3]),
                ("k1", p[4]),
                ("k2", p[5]),
                ("k3", p[6]),
                ("k4", p[7]),
            ],
        ),
        "FULL_OPENCV" if p[9..12].iter().all(|v| *v == 0.0) => (
            "OPENCV",
            vec![
                ("fl_x", p[0]),
                ("fl_y", p[1]),
                ("cx", p[2]),
                ("cy", p[3]),
                ("k1", p[4]),
                ("k2", p[5]),
                ("p1", p[6]),
                ("p2", p[7]),
                ("k3", p[8]),
            ],
        ),
        other => {
            return Err(PoseError::parse(
                path,
                format!("camera {} (image {image})", c.id),
                format!(
                    "camera model {other} has no msnerf equivalent (PINHOLE, OPENCV and OPENCV_FISHEYE families are \
                     supported); rerun COLMAP with --ImageReader.camera_model OPENCV"
                ),
            ))
        }
    };
    Ok(PoseCamera { width: c.width, height: c.height, model, keys })
}

/// The tool-independent model: OpenGL camera-to-world in COLMAP's world frame.
pub fn to_pose_model(m: &ColmapModel, path: &Path) -> Result<PoseModel, PoseError> {
    let mut images = Vec::with_capacity(m.images.len());
    for im in &m.images {
        let cam = m.cameras.get(&im.camera_id).ok_or_else(|| {
            PoseError::parse(path, format!("image {}", im.name), format!("camera {} is not in the model", im.camera_id))
        })?;
        let r = quaternion_matrix(im.q).map_err(|e| PoseError::parse(path, format!("image {}", im.name), e))?;
        images.push(PosedImage {
            id: im.id as u64,
            name: im.name.clone(),
            c2w: c2w_from_w2c_opencv(r, im.t),
            camera: camera(cam, path, &im.name)?,
        });
    }
    let points = m
        .points
        .iter()
        .map(|p| PosePoint {
            xyz: p.xyz,
            rgb: p.rgb,
            error: Some(p.error),
            images: p.images.iter().map(|&i| i as u64).collect(),
        })
        .collect();
    let notes = m
        .rigs
        .iter()
        .map(|r| {
            format!(
                "COLMAP rig model: {} rig(s) ({} sensors), {} frame(s); each image posed as cam_from_rig * \
                 rig_from_world, as COLMAP reads it (images file's own poses differ by up to {:.2e} degree and {:.2e} \
                 model units)",
                r.rigs.len(),
                r.rigs.iter().map(|g| g.sensors.len().to_string()).collect::<Vec<_>>().join("+"),
                r.frames.len(),
                r.max_rotation_diff_deg,
                r.max_centre_diff
            )
        })
        .collect();
    Ok(PoseModel { tool: "colmap", images, points, crs: None, notes })
}
