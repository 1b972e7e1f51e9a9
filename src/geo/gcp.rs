//! Ground control points in OpenDroneMap's `gcp_list.txt` (the file ODM, WebODM's GCP editor and most GCP tools
//! write): the first line is the CRS of the coordinates (`EPSG:32632`, `WGS84 UTM 32N`, a PROJ UTM string, or
//! `EPSG:4326` with x = longitude, y = latitude), then one line per observation
//!
//! ```text
//! geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extra ...]
//! ```
//!
//! separated by spaces or tabs; empty lines and lines starting with `#` are skipped (ODM's `GCPFile` rules). The
//! pixel coordinates are in the named image as it came off the camera, x right, y down, the centre of the first
//! pixel at (0, 0) (OpenSfM's `normalized_image_coordinates` adds half a pixel before centring). Observations of
//! one point share its name, or without a name its coordinates (ODM groups by coordinates).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::error::GcpError;
use super::{Crs, CrsKind, Projector};

/// The file name OpenDroneMap looks for in a project folder.
pub const GCP_FILE_NAME: &str = "gcp_list.txt";

/// A surveyed point.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ControlPoint {
    pub name: String,
    /// In the file's CRS (for `EPSG:4326`: longitude, latitude, height).
    pub xyz: [f64; 3],
}

/// One sighting of a point in one image.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GcpObservation {
    /// Index into [`GcpList::points`].
    pub point: usize,
    /// The image's file name as written (matched by its base name).
    pub image: String,
    /// Pixel, centre of the first pixel at (0, 0).
    pub px: [f64; 2],
    /// Line of the file (1-based).
    pub line: usize,
}

/// A parsed `gcp_list.txt`.
#[derive(Debug, Clone)]
pub struct GcpList {
    pub path: PathBuf,
    pub crs: Crs,
    pub points: Vec<ControlPoint>,
    pub observations: Vec<GcpObservation>,
}

/// Reads and checks `path` (module doc).
pub fn read_gcp_list(path: &Path) -> Result<GcpList, GcpError> {
    let bytes = std::fs::read(path).map_err(|e| GcpError::File { path: path.to_path_buf(), reason: e.to_string() })?;
    let text = String::from_utf8(bytes)
        .map_err(|e| GcpError::File { path: path.to_path_buf(), reason: format!("not UTF-8 text ({e})") })?;
    parse_gcp_list(&text, path)
}

/// Parses the text of a `gcp_list.txt` (`path` names it in errors).
pub fn parse_gcp_list(text: &str, path: &Path) -> Result<GcpList, GcpError> {
    let line_err = |line: usize, reason: String| GcpError::Line { path: path.to_path_buf(), line, reason };
    let mut lines = text.trim_start_matches('\u{feff}').lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    let (hl, header) = lines.find(|(_, l)| !l.is_empty()).ok_or_else(|| GcpError::File {
        path: path.to_path_buf(),
        reason: "empty: the first line names the CRS".into(),
    })?;
    let crs = Crs::parse(header).map_err(|e| line_err(hl, format!("the first line names the CRS: {e}")))?;
    if crs.kind == CrsKind::Geocentric {
        return Err(line_err(hl, "a geocentric CRS: give projected or geographic coordinates".into()));
    }
    let mut points: Vec<ControlPoint> = Vec::new();
    let mut by_key: BTreeMap<String, usize> = BTreeMap::new();
    let mut observations = Vec::new();
    for (ln, line) in lines {
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parts: Vec<&str> = line.split_whitespace().collect();
        if parts.len() < 6 {
            return Err(line_err(
                ln,
                format!("{} fields; expected geo_x geo_y geo_z im_x im_y image_name [gcp_name]", parts.len()),
            ));
        }
        let num = |i: usize, what: &str| -> Result<f64, GcpError> {
            parts[i]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| line_err(ln, format!("{what} {:?} is not a finite number", parts[i])))
        };
        let xyz = [num(0, "geo_x")?, num(1, "geo_y")?, num(2, "geo_z")?];
        let px = [num(3, "im_x")?, num(4, "im_y")?];
        if crs.kind == CrsKind::Geographic && !(xyz[1].abs() <= 90.0 && xyz[0].abs() <= 180.0) {
            return Err(line_err(
                ln,
                format!("({}, {}) is not a longitude, latitude in degrees ({})", xyz[0], xyz[1], crs.describe()),
            ));
        }
        let name = parts.get(6).map(|s| s.to_string());
        let key = name.clone().unwrap_or_else(|| format!("{} {} {}", parts[0], parts[1], parts[2]));
        let point = match by_key.get(&key) {
            Some(&i) => {
                if points[i].xyz != xyz {
                    return Err(line_err(
                        ln,
                        format!("point {:?} at {xyz:?}, but an earlier line puts it at {:?}", key, points[i].xyz),
                    ));
                }
                i
            }
            None => {
                let name = name.unwrap_or_else(|| format!("gcp{}", points.len() + 1));
                points.push(ControlPoint { name, xyz });
                by_key.insert(key, points.len() - 1);
                points.len() - 1
            }
        };
        observations.push(GcpObservation { point, image: parts[5].to_string(), px, line: ln });
    }
    if observations.is_empty() {
        return Err(GcpError::File { path: path.to_path_buf(), reason: "no observations after the CRS line".into() });
    }
    Ok(GcpList { path: path.to_path_buf(), crs, points, observations })
}

impl GcpList {
    /// The points' coordinates in the projected CRS `to` (through WGS84 when the file's CRS differs).
    pub fn points_in(&self, to: &Crs) -> Result<Vec<[f64; 3]>, GcpError> {
        let err = |reason: String| GcpError::File { path: self.path.clone(), reason };
        if self.crs.key() == to.key() {
            return Ok(self.points.iter().map(|p| p.xyz).collect());
        }
        let target = Projector::new(to).map_err(|e| err(e.to_string()))?;
        let source = match self.crs.kind {
            CrsKind::Projected => Some(Projector::new(&self.crs).map_err(|e| err(e.to_string()))?),
            _ => None,
        };
        self.points
            .iter()
            .map(|p| {
                let g = match &source {
                    Some(s) => s.to_geodetic(p.xyz),
                    None => Ok([p.xyz[1], p.xyz[0], p.xyz[2]]),
                }
                .and_then(|g| target.from_geodetic(g[0], g[1], g[2]));
                g.map_err(|e| err(format!("point {}: {e}", p.name)))
            })
            .collect()
    }

    /// The file's text (ODM's layout, tab-separated, the CRS line `header`).
    pub fn to_text(&self, header: &str) -> String {
        let mut s = format!("{header}\n");
        for o in &self.observations {
            let p = &self.points[o.point];
            s.push_str(&format!(
                "{:.4}\t{:.4}\t{:.4}\t{:.2}\t{:.2}\t{}\t{}\n",
                p.xyz[0], p.xyz[1], p.xyz[2], o.px[0], o.px[1], o.image, p.name
            ));
        }
        s
    }
}

/// The base name of an image path (`card/0000SET/000/IMG_0001_1.tif` -> `IMG_0001_1.tif`), as GCP files name
/// images.
pub fn image_base_name(name: &str) -> &str {
    name.rsplit(['/', '\\']).next().unwrap_or(name)
}
