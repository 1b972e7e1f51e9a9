//! What an import checks over the whole flight once every capture is written, so that a flight that imports into
//! nothing useful says so by name instead of exiting in silence:
//!
//! - **reflectance plausibility**: per band, the flight's median value and the 95th percentile of the captures'
//!   99th percentiles; reflectance whose bright end stays below [`REFLECTANCE_LOW`] (nearly everything dark: an
//!   irradiance 100 times too high, as a DLS2 scale read as DLS1 gives) or whose median exceeds
//!   [`REFLECTANCE_HIGH`] is implausible for a whole flight;
//! - **registration**: a band whose residual after registration exceeds [`RESIDUAL_LIMIT_PX`] anywhere, or whose
//!   sampled captures' warps disagree by more than that (shared rig warps), is named;
//! - **GPS**: captures without a fix (none, or tags that read 0 N 0 E) and cameras whose clock was not set.

use super::capture::Capture;

/// Reflectance whose 99th percentile stays below this over the flight is implausibly dark.
pub const REFLECTANCE_LOW: f64 = 0.02;
/// Reflectance whose median exceeds this over the flight is implausibly bright.
pub const REFLECTANCE_HIGH: f64 = 1.5;
/// Registration residuals above this many pixels are named.
pub const RESIDUAL_LIMIT_PX: f64 = 1.0;

/// The median and 99th percentile of finite values (NaN when there are none).
pub fn quantiles(values: impl Iterator<Item = f32>) -> [f32; 2] {
    let mut v: Vec<f32> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return [f32::NAN; 2];
    }
    v.sort_by(f32::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    [at(0.5), at(0.99)]
}

/// A band's flight-level statistics from the captures' [median, p99]: (median of medians, p95 of the p99s).
pub fn flight_quantiles(per_capture: &[[f32; 2]]) -> Option<(f64, f64)> {
    let med: Vec<f64> = per_capture.iter().map(|q| q[0] as f64).filter(|x| x.is_finite()).collect();
    let hi: Vec<f64> = per_capture.iter().map(|q| q[1] as f64).filter(|x| x.is_finite()).collect();
    if med.is_empty() || hi.is_empty() {
        return None;
    }
    Some((crate::util::stats::median(&med), crate::util::stats::quantile(&hi, 0.95)))
}

/// The named problem of a band whose reflectance is implausible for a whole flight, or `None`.
pub fn reflectance_problem(band: &str, median: f64, p99: f64) -> Option<String> {
    if p99 < REFLECTANCE_LOW {
        Some(format!(
            "band {band}: reflectance implausibly low for a whole flight (99th percentile {p99:.4}, median {median:.4}; \
             a sunlit scene reaches 0.05-0.6): the irradiance is likely in the wrong units (a DLS2 file read without \
             its 0.01 scale gives 100x too little) or the panel's reflectance is wrong"
        ))
    } else if median > REFLECTANCE_HIGH {
        Some(format!(
            "band {band}: reflectance implausibly high for a whole flight (median {median:.3}, 99th percentile \
             {p99:.3}): the irradiance is likely too low (wrong units or a shaded light sensor)"
        ))
    } else {
        None
    }
}

/// Registration warnings: per band, the largest residual over the captures (with the capture) and the shared
/// warps' spread.
pub fn registration_warnings(
    bands: &[String],
    worst: &[Option<(f64, String)>],
    spread_px: Option<&[f64]>,
) -> Vec<String> {
    let mut out = Vec::new();
    for (b, w) in bands.iter().zip(worst) {
        if let Some((r, cap)) = w.as_ref().filter(|(r, _)| *r > RESIDUAL_LIMIT_PX) {
            out.push(format!(
                "band {b}: registration residual up to {r:.2} px (capture {cap}): above {RESIDUAL_LIMIT_PX} px, the \
                 band is not aligned with the reference there"
            ));
        }
    }
    for (b, s) in bands.iter().zip(spread_px.unwrap_or(&[])) {
        if *s > RESIDUAL_LIMIT_PX {
            out.push(format!(
                "band {b}: the sampled captures' warps differ by up to {s:.2} px from the shared one: the rig's \
                 registration is uncertain by that much"
            ));
        }
    }
    out
}

/// GPS and clock warnings for the captures (reference band `r`); returns (warnings, names without a fix).
pub fn gps_warnings(captures: &[Capture], r: usize) -> (Vec<String>, Vec<String>) {
    let mut out = Vec::new();
    let missing: Vec<(String, Option<String>)> = captures
        .iter()
        .filter(|c| c.bands[r].meta.gps.is_none())
        .map(|c| (c.name(), c.bands[r].meta.gps_rejected.clone()))
        .collect();
    let list = |v: &[(String, Option<String>)]| {
        let mut s: Vec<String> = v
            .iter()
            .take(5)
            .map(|(n, why)| format!("{n}{}", why.as_ref().map_or(String::new(), |w| format!(": {w}"))))
            .collect();
        if v.len() > 5 {
            s.push(format!("and {} more", v.len() - 5));
        }
        s.join("; ")
    };
    if !missing.is_empty() && missing.len() == captures.len() {
        out.push(format!(
            "no capture has a GPS fix ({}): the pose priors are unknown (every camera at one point) and the outputs \
             can carry no CRS; pose the flight with `msnerf sfm --no-georef` or `msnerf import poses`",
            list(&missing)
        ));
    } else if !missing.is_empty() {
        out.push(format!(
            "{} of {} captures have no GPS fix ({}): their pose priors are the flight's mean position, and \
             geo-registration leaves them out",
            missing.len(),
            captures.len(),
            list(&missing)
        ));
    }
    let unset: Vec<String> = captures.iter().filter(|c| !c.bands[r].meta.clock_set).map(|c| c.name()).collect();
    if !unset.is_empty() {
        out.push(format!(
            "{} capture(s) carry an unset clock (a date before 2000: no GPS time), e.g. {}: the sun's position for \
             the light sensor is unknown there",
            unset.len(),
            unset[0]
        ));
    }
    (out, missing.into_iter().map(|(n, _)| n).collect())
}
