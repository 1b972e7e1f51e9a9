//! Geo-registration of an SfM model to the frames' GPS: a robust similarity fit from model camera centres to the
//! projected GPS positions (`crate::maths::similarity`), applied to poses and points.
//!
//! Robustness: fit on all pairs, drop those whose residual exceeds `max(3 x median, 3 x the GPS noise floor
//! `min_error_m`)`, refit; three rounds. A pair dropped is a GPS glitch or a misregistered camera: both are listed by
//! frame name. At least 3 pairs must remain and they must not lie on a line (a straight single-strip flight
//! leaves the roll about the strip free: refused, named).
//!
//! With ground control ([`super::control`]) the final fit weighs every kept GPS pair by `1 / gps_error^2` and every
//! placed control point by `1 / CONTROL_SIGMA_M^2`, and estimates the GPS's datum shift alongside (a constant
//! offset of every fix, reported): three control points fix the similarity (the datum shift and the tilt of noisy
//! fixes vanish), one or two pin its translation while the GPS still gives rotation and scale. Each point's
//! residual is reported, and its check residual: the fit made without it, as Metashape's check points measure.

use super::control::Placed;
use crate::maths::similarity::{fit_similarity, fit_similarity_weighted, Similarity};
use crate::poses::model::PoseModel;

/// The standard deviation assumed for a control point (surveyed and placed in the images), metres; it weighs the
/// points against the GPS.
pub const CONTROL_SIGMA_M: f64 = 0.02;

/// One control point after the fit.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ControlResidual {
    pub name: String,
    pub views: usize,
    pub reprojection_px: f64,
    /// Fitted minus surveyed (east, north, up; metres).
    pub residual_m: [f64; 3],
    /// The same with the point left out of the fit (None when the rest do not fix a similarity).
    pub check_m: Option<[f64; 3]>,
}

/// How the model sits on the ground control.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ControlReport {
    pub points: Vec<ControlResidual>,
    /// RMS of the residuals' lengths (metres).
    pub rms_m: f64,
    /// RMS of the check residuals' lengths (metres): the absolute accuracy to expect between the points.
    pub check_rms_m: Option<f64>,
    /// The GPS's datum shift the control points reveal (the fixes' mean offset from the fitted frame; east, north,
    /// up, metres), when there are both.
    pub gps_shift_m: Option<[f64; 3]>,
    /// Observations and points left out, each named.
    pub notes: Vec<String>,
    /// The bundle adjustment on the control points (`super::adjusted`), when it ran: the residuals, check
    /// residuals and datum shift above are then the adjusted model's.
    pub adjustment: Option<super::adjusted::AdjustmentReport>,
}

/// The fit and how well the GPS agrees with it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct GeoFit {
    #[serde(skip)]
    pub similarity: Similarity,
    pub scale: f64,
    pub pairs: usize,
    /// Frames whose GPS disagreed with the model (left out of the fit).
    pub rejected: Vec<String>,
    pub rms_m: f64,
    pub max_m: f64,
    /// Ground control, when the dataset has it.
    pub control: Option<ControlReport>,
}

impl GeoFit {
    /// What the fit says, one line per fact (the commands print them, the process report lists them).
    pub fn describe(&self) -> Vec<String> {
        let mut v = vec![format!(
            "GPS: {} fixes used, scale {:.4}, residual rms {:.3} m, max {:.3} m",
            self.pairs, self.scale, self.rms_m, self.max_m
        )];
        v.extend(self.rejected.iter().map(|f| format!("GPS disagrees with the model (left out of the fit): {f}")));
        if let Some(c) = &self.control {
            v.push(format!(
                "ground control: {} point(s), residual rms {:.3} m, check rms {}",
                c.points.len(),
                c.rms_m,
                c.check_rms_m.map_or("n/a".into(), |r| format!("{r:.3} m (each point left out of the fit in turn)"))
            ));
            if let Some(a) = &c.adjustment {
                v.push(format!(
                    "bundle adjustment on the control points: {} iterations, {} observations, reprojection rms \
                     {:.2} -> {:.2} px; before it (similarity only) residual rms {:.3} m, check rms {}",
                    a.iterations,
                    a.observations,
                    a.rms_px_before,
                    a.rms_px_after,
                    a.similarity_rms_m,
                    a.similarity_check_rms_m.map_or("n/a".into(), |r| format!("{r:.3} m"))
                ));
            }
            if let Some(g) = c.gps_shift_m {
                v.push(format!(
                    "GPS datum shift found by the control points: E {:+.3}, N {:+.3}, U {:+.3} m",
                    g[0], g[1], g[2]
                ));
            }
            let e = |r: [f64; 3]| format!("({:+.3}, {:+.3}, {:+.3}) m", r[0], r[1], r[2]);
            for p in &c.points {
                v.push(format!(
                    "  {}: {} views, reprojection {:.2} px, residual E/N/U {}, check {}",
                    p.name,
                    p.views,
                    p.reprojection_px,
                    e(p.residual_m),
                    p.check_m.map_or("n/a".into(), e)
                ));
            }
            v.extend(c.notes.iter().map(|n| format!("  {n}")));
        }
        v
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Fits `model -> gps` on named pairs.
pub fn robust_fit(names: &[String], model: &[[f64; 3]], gps: &[[f64; 3]], min_error_m: f64) -> Result<GeoFit, String> {
    let mut keep: Vec<usize> = (0..names.len()).collect();
    let mut sim = None;
    for _round in 0..3 {
        let src: Vec<[f64; 3]> = keep.iter().map(|&i| model[i]).collect();
        let dst: Vec<[f64; 3]> = keep.iter().map(|&i| gps[i]).collect();
        let s = fit_similarity(&src, &dst).ok_or_else(|| {
            format!(
                "{} camera(s) with GPS{}: a similarity needs at least 3 that are not on one line",
                keep.len(),
                if keep.len() >= 3 { ", on one line" } else { "" }
            )
        })?;
        let res: Vec<f64> = (0..names.len()).map(|i| dist(s.apply(model[i]), gps[i])).collect();
        sim = Some(s);
        let mut sorted: Vec<f64> = keep.iter().map(|&i| res[i]).collect();
        sorted.sort_by(f64::total_cmp);
        let limit = (3.0 * sorted[sorted.len() / 2]).max(3.0 * min_error_m);
        let next: Vec<usize> = (0..names.len()).filter(|&i| res[i] <= limit).collect();
        if next == keep {
            break;
        }
        keep = next;
    }
    let s = sim.expect("one round ran");
    let src: Vec<[f64; 3]> = keep.iter().map(|&i| model[i]).collect();
    let dst: Vec<[f64; 3]> = keep.iter().map(|&i| gps[i]).collect();
    let s = fit_similarity(&src, &dst).unwrap_or(s);
    let res: Vec<f64> = keep.iter().map(|&i| dist(s.apply(model[i]), gps[i])).collect();
    Ok(GeoFit {
        similarity: s,
        scale: s.scale,
        pairs: keep.len(),
        rejected: (0..names.len()).filter(|i| !keep.contains(i)).map(|i| names[i].clone()).collect(),
        rms_m: rms(res.iter().copied()),
        max_m: res.iter().copied().fold(0.0, f64::max),
        control: None,
    })
}

/// Root mean square of `v` (0 when empty).
fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

/// The fit with ground control: GPS pairs (`names`, `model`, `gps`; robustly filtered as [`robust_fit`] when there
/// are three or more) and the `control` points placed in the model's frame, weighted as the module doc says.
/// `notes` are the placing's (carried into the report).
pub fn fit_with_control(
    names: &[String],
    model: &[[f64; 3]],
    gps: &[[f64; 3]],
    min_error_m: f64,
    control: &[Placed],
    notes: Vec<String>,
) -> Result<GeoFit, String> {
    let gps_fit = if names.len() >= 3 { Some(robust_fit(names, model, gps, min_error_m)?) } else { None };
    let kept: Vec<usize> = match &gps_fit {
        Some(f) => (0..names.len()).filter(|&i| !f.rejected.contains(&names[i])).collect(),
        None => Vec::new(),
    };
    let w_gps = 1.0 / min_error_m.max(1e-3).powi(2);
    let w_gcp = 1.0 / (CONTROL_SIGMA_M * CONTROL_SIGMA_M);
    let fit = |skip: Option<usize>, bias: [f64; 3]| {
        let (mut src, mut dst, mut w) = (Vec::new(), Vec::new(), Vec::new());
        for &i in &kept {
            src.push(model[i]);
            dst.push([gps[i][0] - bias[0], gps[i][1] - bias[1], gps[i][2] - bias[2]]);
            w.push(w_gps);
        }
        for (j, c) in control.iter().enumerate() {
            if Some(j) != skip {
                src.push(c.model);
                dst.push(c.xyz);
                w.push(w_gcp);
            }
        }
        fit_similarity_weighted(&src, &dst, &w)
    };
    // The GPS's datum shift is a parameter here: the control points fix the frame, the fixes' mean offset from it
    // is the shift, and only what varies between fixes (rotation, scale) is taken from them. Alternating the two
    // converges by the weights' ratio per round.
    let solve = |skip: Option<usize>| -> Option<(Similarity, [f64; 3])> {
        let used = control.len() - usize::from(skip.is_some());
        let mut bias = [0.0; 3];
        let mut s = fit(skip, bias)?;
        if used == 0 || kept.is_empty() {
            return Some((s, bias));
        }
        for _ in 0..100 {
            let next: [f64; 3] = std::array::from_fn(|k| {
                kept.iter().map(|&i| gps[i][k] - s.apply(model[i])[k]).sum::<f64>() / kept.len() as f64
            });
            let moved = dist(next, bias);
            bias = next;
            s = fit(skip, bias)?;
            if moved < 1e-6 {
                break;
            }
        }
        Some((s, bias))
    };
    let (s, gps_shift) = solve(None).ok_or_else(|| {
        format!(
            "{} control point(s) and {} GPS fix(es) do not fix a similarity: at least 3 positions that are not on \
             one line are needed{}",
            control.len(),
            kept.len(),
            if notes.is_empty() { String::new() } else { format!(" ({})", notes.join("; ")) }
        )
    })?;
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let points: Vec<ControlResidual> = control
        .iter()
        .enumerate()
        .map(|(j, c)| ControlResidual {
            name: c.name.clone(),
            views: c.views,
            reprojection_px: c.reprojection_px,
            residual_m: sub(s.apply(c.model), c.xyz),
            check_m: solve(Some(j)).map(|(t, _)| sub(t.apply(c.model), c.xyz)),
        })
        .collect();
    // The GPS residuals as the user sees them: against the final frame, the datum shift included.
    let res: Vec<f64> = kept.iter().map(|&i| dist(s.apply(model[i]), gps[i])).collect();
    Ok(GeoFit {
        similarity: s,
        scale: s.scale,
        pairs: kept.len(),
        rejected: gps_fit.map(|f| f.rejected).unwrap_or_default(),
        rms_m: rms(res.iter().copied()),
        max_m: res.iter().copied().fold(0.0, f64::max),
        control: Some(ControlReport::new(
            points,
            (!control.is_empty() && !kept.is_empty()).then_some(gps_shift),
            notes,
        )),
    })
}

impl ControlReport {
    /// The report of `points`, their RMS and check RMS computed from them.
    pub fn new(points: Vec<ControlResidual>, gps_shift_m: Option<[f64; 3]>, notes: Vec<String>) -> ControlReport {
        let mut r =
            ControlReport { points: Vec::new(), rms_m: 0.0, check_rms_m: None, gps_shift_m, notes, adjustment: None };
        r.set_points(points);
        r
    }

    /// Replaces the points, and the RMS and check RMS with theirs.
    pub fn set_points(&mut self, points: Vec<ControlResidual>) {
        let len = |v: [f64; 3]| dist(v, [0.0; 3]);
        let checks: Vec<f64> = points.iter().filter_map(|p| p.check_m.map(len)).collect();
        self.rms_m = rms(points.iter().map(|p| len(p.residual_m)));
        self.check_rms_m = (!checks.is_empty()).then(|| rms(checks.iter().copied()));
        self.points = points;
    }
}

/// Applies `s` to every pose (rotation turned, centre mapped) and point of `m`.
pub fn apply(m: &mut PoseModel, s: &Similarity) {
    for im in &mut m.images {
        let c = s.apply([im.c2w[0][3], im.c2w[1][3], im.c2w[2][3]]);
        let cols: Vec<[f64; 3]> = (0..3).map(|j| s.rotate([im.c2w[0][j], im.c2w[1][j], im.c2w[2][j]])).collect();
        for i in 0..3 {
            for (j, col) in cols.iter().enumerate() {
                im.c2w[i][j] = col[i];
            }
            im.c2w[i][3] = c[i];
        }
    }
    for p in &mut m.points {
        p.xyz = s.apply(p.xyz);
    }
}
