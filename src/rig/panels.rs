//! Calibration-panel captures found among a flight's captures (`msnerf import rig` without `--panel`, and
//! `msnerf process`), as Metashape's "locate reflectance panels" and the cameras' own panel mode do: a panel
//! capture is taken on the ground before (or after) the flight, so its GPS altitude lies far below the flight's,
//! and its reference band shows the panel (found as [`super::panel::detect_panel`] finds it).
//!
//! A capture is "on the ground" when its altitude is more than `max(10 m, half the flight's height range)`
//! below the median altitude of the captures with a fix. Those that show a panel are panel captures; those that
//! do not are left out of the flight with a warning (a take-off or landing shot). A panel capture between flight
//! captures is named: it still calibrates, but a panel mid-flight is worth a look (a landing to re-calibrate, or
//! a mislabelled folder).

use super::capture::Capture;
use super::error::RigError;
use super::meta::read_pixels;
use super::panel::detect_panel;
use super::radiometry::{saturation_level, to_radiance};

/// The flight split into panel captures and the rest.
#[derive(Debug, Default)]
pub struct PanelSplit {
    pub panels: Vec<Capture>,
    pub flight: Vec<Capture>,
    /// Ground-level captures without a panel, left out: (capture name, why).
    pub left_out: Vec<(String, String)>,
    pub warnings: Vec<String>,
}

fn altitude(c: &Capture, r: usize) -> Option<f64> {
    c.bands[r].meta.gps.and_then(|g| g.altitude)
}

/// Whether the capture's reference band shows a calibration panel.
fn shows_panel(c: &Capture, r: usize) -> Result<bool, RigError> {
    let b = &c.bands[r];
    let raw = read_pixels(&b.meta)?;
    let (rad, _) = to_radiance(b, &raw);
    let sat = saturation_level(b);
    let saturated: Vec<bool> = raw.iter().map(|v| *v >= sat).collect();
    Ok(detect_panel(&rad, &saturated, &b.meta.path).is_ok())
}

/// Splits `captures` (in capture order) into panel captures and the flight; `r` is the reference band index.
pub fn split_panel_captures(captures: Vec<Capture>, r: usize) -> Result<PanelSplit, RigError> {
    let mut alts: Vec<f64> = captures.iter().filter_map(|c| altitude(c, r)).collect();
    let mut out = PanelSplit::default();
    if alts.len() < 3 {
        out.flight = captures;
        return Ok(out);
    }
    alts.sort_by(f64::total_cmp);
    let median = alts[alts.len() / 2];
    let range = median - alts[0];
    let threshold = median - (0.5 * range).max(10.0);
    let ground: Vec<bool> = captures.iter().map(|c| altitude(c, r).is_some_and(|a| a < threshold)).collect();
    let first_flight = ground.iter().position(|g| !g);
    let last_flight = ground.iter().rposition(|g| !g);
    for (i, (c, g)) in captures.into_iter().zip(ground).enumerate() {
        if !g {
            out.flight.push(c);
            continue;
        }
        let alt = altitude(&c, r).unwrap_or(f64::NAN);
        if shows_panel(&c, r)? {
            if first_flight.is_some_and(|f| i > f) && last_flight.is_some_and(|l| i < l) {
                out.warnings.push(format!(
                    "capture {} ({}) is a calibration-panel capture in the middle of the flight (altitude {alt:.1} m \
                     against the flight's {median:.1} m): used to calibrate, left out of the flight",
                    c.name(),
                    c.key
                ));
            }
            out.panels.push(c);
        } else {
            let why = format!(
                "taken on the ground (altitude {alt:.1} m against the flight's {median:.1} m) and shows no \
                 calibration panel: a take-off or landing shot"
            );
            out.warnings.push(format!("capture {} left out: {why}", c.name()));
            out.left_out.push((c.name(), why));
        }
    }
    Ok(out)
}
