//! Ground control for a simulated raw flight (`--gcp N`): N surveyed points on open ground spread over the flight
//! (the four corners of the area the cameras cover, inset by a fifth, then its centre, then seeded places), and
//! `gcp_list.txt` in OpenDroneMap's layout ([`crate::geo::gcp`]): every capture that sees a point unoccluded, at
//! least [`EDGE_PX`] inside the raw frame, gives one observation in one band's raw file (the bands taken in turn,
//! as a user clicks in whichever band is open), at the point's true projection through that band's lens and rig
//! plus a click error of [`CLICK_NOISE_PX`] per axis. The coordinates are the truth's (a survey's few centimetres
//! are below what the products resolve); the markers themselves are not drawn, as no stage detects them.

use std::path::Path;

use super::forward::{project, RigPose};
use super::profile::SensorProfile;
use crate::geo::gcp::{ControlPoint, GcpList, GcpObservation};
use crate::sim::effects::{hash4, normal};
use crate::sim::error::SimError;
use crate::sim::geometry::HitKind;
use crate::sim::render::Prepared;

/// Standard deviation of a click, pixels per axis.
pub const CLICK_NOISE_PX: f64 = 0.5;
/// Observations keep this far inside the raw frame (pixels).
pub const EDGE_PX: f64 = 4.0;
const STREAM_GCP: u64 = 0x0067_6370;

/// A point on open, level ground near (x, y) (local frame), searched outwards on a square spiral of 1 m steps.
fn open_ground(prep: &Prepared, x: f64, y: f64) -> Option<[f64; 3]> {
    for r in 0..40i32 {
        for (dx, dy) in (-r..=r).flat_map(|i| (-r..=r).map(move |j| (i, j))).filter(|(i, j)| i.abs().max(j.abs()) == r)
        {
            let o = [x + f64::from(dx), y + f64::from(dy), 1000.0];
            let hit = prep.world.trace(o, [0.0, 0.0, -1.0]);
            if hit.kind == HitKind::Ground && hit.normal[2] > 0.999 {
                return Some([o[0], o[1], o[2] - hit.t]);
            }
        }
    }
    None
}

/// `n` control points (local frame) over the area under the cameras.
pub fn place(prep: &Prepared, n: usize, seed: u64) -> Result<Vec<[f64; 3]>, SimError> {
    let xs = prep.poses.iter().map(|m| m[0][3]);
    let ys = prep.poses.iter().map(|m| m[1][3]);
    let (x0, x1) = (xs.clone().fold(f64::INFINITY, f64::min), xs.fold(f64::NEG_INFINITY, f64::max));
    let (y0, y1) = (ys.clone().fold(f64::INFINITY, f64::min), ys.fold(f64::NEG_INFINITY, f64::max));
    let (ix, iy) = ((x1 - x0) / 5.0, (y1 - y0) / 5.0);
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let (x, y) = match k {
            0 => (x0 + ix, y0 + iy),
            1 => (x1 - ix, y0 + iy),
            2 => (x1 - ix, y1 - iy),
            3 => (x0 + ix, y1 - iy),
            4 => (0.5 * (x0 + x1), 0.5 * (y0 + y1)),
            _ => {
                let u = |i| (hash4(seed, STREAM_GCP, k as u64, i) >> 11) as f64 / (1u64 << 53) as f64;
                (x0 + ix + u(0) * 3.0 * ix, y0 + iy + u(1) * 3.0 * iy)
            }
        };
        out.push(open_ground(prep, x, y).ok_or_else(|| SimError::Option {
            key: "gcp".into(),
            reason: format!("no open, level ground within 40 m of ({x:.1}, {y:.1}) for control point {}", k + 1),
        })?);
    }
    Ok(out)
}

/// The flight's `gcp_list.txt` and the exact observations: `captures` are (capture number, view) pairs; `file`
/// names a capture's band file. Returns the list (world coordinates in the scene's CRS) and, per observation, the
/// exact projection.
pub fn observations(
    prep: &Prepared,
    profile: &SensorProfile,
    captures: &[(usize, usize)],
    points: &[[f64; 3]],
    seed: u64,
    file: &dyn Fn(usize, usize) -> String,
) -> (GcpList, Vec<[f64; 2]>) {
    let crs = prep.crs.clone().expect("a raw rig's scene has a crs");
    let off = prep.world_offset;
    let rigs: Vec<RigPose> = profile.bands.iter().map(|b| RigPose::of(profile, b)).collect();
    let (w, h) = (f64::from(profile.width), f64::from(profile.height));
    let mut list = GcpList { path: "gcp_list.txt".into(), crs, points: Vec::new(), observations: Vec::new() };
    let mut exact = Vec::new();
    for (k, p) in points.iter().enumerate() {
        list.points.push(ControlPoint {
            name: format!("gcp{:02}", k + 1),
            xyz: [p[0] + off[0], p[1] + off[1], p[2] + off[2]],
        });
        for (i, &(number, view)) in captures.iter().enumerate() {
            let bi = (k + i) % profile.bands.len();
            let c2w = prep.poses[view];
            let Some((u, v)) = project(&profile.bands[bi].lens, &rigs[bi], &c2w, *p) else { continue };
            if !(u >= EDGE_PX && v >= EDGE_PX && u <= w - 1.0 - EDGE_PX && v <= h - 1.0 - EDGE_PX) {
                continue;
            }
            let to_cam = [c2w[0][3] - p[0], c2w[1][3] - p[1], c2w[2][3] - p[2]];
            let n = (to_cam[0] * to_cam[0] + to_cam[1] * to_cam[1] + to_cam[2] * to_cam[2]).sqrt();
            if prep.world.occluded([p[0], p[1], p[2] + 1e-3], to_cam.map(|c| c / n)) {
                continue;
            }
            let key = (k as u64) << 32 | number as u64;
            let px = [
                u + CLICK_NOISE_PX * normal(seed, STREAM_GCP, key, 0),
                v + CLICK_NOISE_PX * normal(seed, STREAM_GCP, key, 1),
            ];
            let image = file(number, bi);
            list.observations.push(GcpObservation { point: k, image, px, line: list.observations.len() + 2 });
            exact.push([u, v]);
        }
    }
    (list, exact)
}

/// Writes `root/gcp_list.txt` (header `EPSG:n`) and `root/truth/gcp.json`.
pub fn write(root: &Path, list: &GcpList, exact: &[[f64; 2]]) -> Result<(), SimError> {
    let path = root.join(crate::geo::gcp::GCP_FILE_NAME);
    std::fs::write(&path, list.to_text(&list.crs.key())).map_err(SimError::io(&path))?;
    let truth = root.join("truth/gcp.json");
    let obs: Vec<_> = list
        .observations
        .iter()
        .zip(exact)
        .map(|(o, e)| serde_json::json!({"point": list.points[o.point].name, "image": o.image, "px": e, "clicked": o.px}))
        .collect();
    let v = serde_json::json!({
        "note": "the control points' true positions and each observation's exact projection (pixel centres at integers) \
                 beside the clicked one written in gcp_list.txt",
        "crs": list.crs.key(),
        "click_noise_px": CLICK_NOISE_PX,
        "points": list.points,
        "observations": obs,
    });
    std::fs::write(&truth, serde_json::to_string_pretty(&v).expect("json")).map_err(SimError::io(&truth))
}
