//! Ground control carried from the raw band images into the dataset: each observation of OpenDroneMap's
//! `gcp_list.txt` ([`crate::geo::gcp`]) names a raw band file and a pixel in it; here it becomes a pixel of the
//! imported frame (the reference band's undistorted camera, cropped), by inverting the one mapping the import
//! resamples with ([`super::lens::source_pixel`]: registration warp, then the band's lens) with Newton steps. The
//! points go into `transforms.json` as `ground_control` (docs/dataset.md), in the dataset's CRS, for `sfm` to
//! georeference with.

use std::collections::HashMap;

use serde_json::{json, Value};

use super::capture::Capture;
use super::error::RigError;
use super::frame::{target_for, FrameOut};
use super::lens::{source_pixel, Target};
use super::warp::Warp;
use crate::geo::gcp::{image_base_name, GcpList};
use crate::geo::Crs;

/// Where GCPs come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GcpSource {
    /// The input folder's `gcp_list.txt` when there is one (as OpenDroneMap finds it in a project folder).
    Auto,
    File(std::path::PathBuf),
    Off,
}

impl GcpSource {
    /// From the commands' `--gcp FILE` and `--no-gcp`.
    pub fn from_flags(file: Option<&std::path::PathBuf>, off: bool) -> GcpSource {
        match (file, off) {
            (_, true) => GcpSource::Off,
            (Some(f), false) => GcpSource::File(f.clone()),
            (None, false) => GcpSource::Auto,
        }
    }

    /// The file to read for a flight in `input`: the one given, or `input`'s `gcp_list.txt` when it exists.
    pub fn path(&self, input: &std::path::Path) -> Option<std::path::PathBuf> {
        match self {
            GcpSource::Auto => Some(input.join(crate::geo::gcp::GCP_FILE_NAME)).filter(|p| p.is_file()),
            GcpSource::File(p) => Some(p.clone()),
            GcpSource::Off => None,
        }
    }
}

/// The target pixel whose source pixel is `raw` (None when Newton does not reach it to 1e-4 px).
pub fn invert_source_pixel(
    target: &Target,
    lens: Option<&super::calib::Lens>,
    warp: &Warp,
    raw: [f64; 2],
) -> Option<[f64; 2]> {
    let f = |x: f64, y: f64| source_pixel(target, lens, warp, x, y);
    let (mut x, mut y) = (raw[0], raw[1]);
    for _ in 0..30 {
        let (u, v) = f(x, y);
        let (ex, ey) = (u - raw[0], v - raw[1]);
        if ex.hypot(ey) < 1e-4 {
            return Some([x, y]);
        }
        let h = 0.5;
        let (ux, vx) = f(x + h, y);
        let (uy, vy) = f(x, y + h);
        let (a, b, c, d) = ((ux - u) / h, (uy - u) / h, (vx - v) / h, (vy - v) / h);
        let det = a * d - b * c;
        if !det.is_finite() || det.abs() < 1e-9 {
            return None;
        }
        x -= (d * ex - b * ey) / det;
        y -= (-c * ex + a * ey) / det;
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
    }
    None
}

/// The `ground_control` value of `transforms.json` for the imported `frames` of `captures`, with the
/// observations that cannot be used named in `warnings`. Errors when no point is left with two observations.
pub fn dataset_ground_control(
    list: &GcpList,
    crs: &Crs,
    captures: &[Capture],
    frames: &[FrameOut],
    ref_idx: usize,
    undistort: bool,
    warnings: &mut Vec<String>,
) -> Result<Value, RigError> {
    let err = |reason: String| RigError::Output { path: list.path.clone(), reason };
    let xyz = list.points_in(crs).map_err(|e| err(e.to_string()))?;
    let mut files: HashMap<String, (usize, usize)> = HashMap::new();
    for (ci, c) in captures.iter().enumerate() {
        for (bi, b) in c.bands.iter().enumerate() {
            files.insert(image_base_name(&b.meta.path.to_string_lossy()).to_ascii_lowercase(), (ci, bi));
        }
        // The imported frame itself (pixel coordinates in the dataset's image), by its file name.
        files.insert(image_base_name(&frames[ci].file).to_ascii_lowercase(), (ci, usize::MAX));
    }
    let mut obs: Vec<Vec<Value>> = vec![Vec::new(); list.points.len()];
    let mut unknown = Vec::new();
    for o in &list.observations {
        let Some(&(ci, bi)) = files.get(&image_base_name(&o.image).to_ascii_lowercase()) else {
            unknown.push(format!("{} (line {})", o.image, o.line));
            continue;
        };
        let f = &frames[ci];
        let px = if bi == usize::MAX {
            // Already in the frame (centre of the first pixel at 0, as in the file).
            Some([o.px[0] + 0.5, o.px[1] + 0.5])
        } else {
            let cap = &captures[ci];
            let target = target_for(cap, ref_idx, undistort);
            let lens = cap.bands[bi].lens.filter(|_| undistort);
            invert_source_pixel(&target, lens.as_ref(), &f.registration[bi].warp, o.px)
                .map(|t| [t[0] + f.cx - target.cx + 0.5, t[1] + f.cy - target.cy + 0.5])
        };
        match px {
            Some(p) if p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= f.width as f64 && p[1] <= f.height as f64 => {
                obs[o.point].push(json!({"file_path": f.file, "px": p, "image": o.image, "line": o.line}));
            }
            Some(_) => warnings.push(format!(
                "{}, line {}: {} at ({:.1}, {:.1}) px falls outside the imported frame (the bands' common crop); \
                 not used",
                list.path.display(),
                o.line,
                o.image,
                o.px[0],
                o.px[1]
            )),
            None => warnings.push(format!(
                "{}, line {}: ({:.1}, {:.1}) px of {} does not map into the frame; not used",
                list.path.display(),
                o.line,
                o.px[0],
                o.px[1],
                o.image
            )),
        }
    }
    if !unknown.is_empty() {
        warnings.push(format!(
            "{}: {} observation(s) name images that are not among the flight's captures: {}",
            list.path.display(),
            unknown.len(),
            unknown.iter().take(5).cloned().collect::<Vec<_>>().join(", ")
        ));
    }
    let mut points = Vec::new();
    for (i, p) in list.points.iter().enumerate() {
        if obs[i].len() < 2 {
            warnings.push(format!(
                "{}: point {} has {} usable observation(s); a point needs two images to be placed: not used",
                list.path.display(),
                p.name,
                obs[i].len()
            ));
            continue;
        }
        points.push(json!({"name": p.name, "xyz": xyz[i], "observations": obs[i]}));
    }
    if points.is_empty() {
        return Err(err(format!(
            "no ground control point has two usable observations in the flight's images ({} observation(s) read)",
            list.observations.len()
        )));
    }
    Ok(json!({
        "source": list.path.display().to_string(),
        "crs": crs.key(),
        "file_crs": list.crs.key(),
        "pixels": "the frame's pixels, the image's corner at (0, 0) (pixel centres at +0.5, as the intrinsics)",
        "points": points,
    }))
}
