//! Geo-registration of an SfM model to the frames' GPS: a robust similarity fit from model camera centres to the
//! projected GPS positions (`crate::maths::similarity`), applied to poses and points.
//!
//! Robustness: fit on all pairs, drop those whose residual exceeds `max(3 x median, 3 x the GPS noise floor
//! `min_error_m`)`, refit; three rounds. A pair dropped is a GPS glitch or a misregistered camera: both are listed by
//! frame name. At least 3 pairs must remain and they must not lie on a line (a straight single-strip flight
//! leaves the roll about the strip free: refused, named).

use crate::maths::similarity::{fit_similarity, Similarity};
use crate::poses::model::PoseModel;

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
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    Ok(GeoFit {
        similarity: s,
        scale: s.scale,
        pairs: keep.len(),
        rejected: (0..names.len()).filter(|i| !keep.contains(i)).map(|i| names[i].clone()).collect(),
        rms_m: rms,
        max_m: res.iter().copied().fold(0.0, f64::max),
    })
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
