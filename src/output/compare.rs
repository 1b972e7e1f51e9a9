//! Cloud-to-cloud comparison (`msnerf compare-cloud --pred A --ref B`).
//!
//! - **Accuracy**: distance from each predicted point to its nearest reference point (mean, median, RMSE, max).
//! - **Completeness**: the same from each reference point to the nearest predicted point.
//! - **Precision / recall / F-score** at a distance threshold τ (default 0.1 m): the fraction of predicted
//!   (reference) points whose nearest neighbour in the other cloud is closer than τ, and `2PR/(P+R)` (Tanks and
//!   Temples' definition, strict `<`).
//! - **Planar and elevation errors** of the matched pairs (every predicted point and its nearest reference
//!   point), as the paper's Tables 6–7 report them: the Euclidean distance `ED`, the planar distance
//!   `√(dx² + dy²)` and the elevation distance `|dz|` (z up), averaged; plus RMSEs and the signed mean dz
//!   (predicted minus reference; a vertical bias).
//! - **Per-band reflectance error** (MAE, RMSE, bias = mean(pred − ref)) over the matched pairs closer than τ,
//!   when both clouds carry bands; bands are paired by centre wavelength (nearest within 25 nm), or by equal
//!   name when centres are missing.
//!
//! Nearest neighbours come from [`KdTree`] (exact f64); queries run on all cores.

use serde::Serialize;

use super::image::fmt_nm;
use super::metrics::report::finite_or_null;
use super::pointcloud::filter::par_map;
use super::pointcloud::kdtree::KdTree;
use super::pointcloud::PointCloud;
use super::{OutputError, Result};

/// Comparison options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompareOptions {
    /// Distance threshold τ in the clouds' unit (metres for georeferenced clouds).
    pub threshold: f64,
    /// Largest centre-wavelength difference for pairing bands.
    pub band_tolerance_nm: f64,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions { threshold: 0.1, band_tolerance_nm: 25.0 }
    }
}

/// Summary of a set of distances.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DistanceStats {
    pub count: usize,
    #[serde(serialize_with = "finite_or_null")]
    pub mean: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub median: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub rmse: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub max: f64,
}

impl DistanceStats {
    /// Mean, median (mean of the two middle values for an even count), RMSE and max.
    pub fn of(d: &[f64]) -> DistanceStats {
        if d.is_empty() {
            return DistanceStats { count: 0, mean: f64::NAN, median: f64::NAN, rmse: f64::NAN, max: f64::NAN };
        }
        let n = d.len() as f64;
        let mut s = d.to_vec();
        s.sort_unstable_by(|a, b| a.total_cmp(b));
        let m = s.len() / 2;
        let median = if s.len() % 2 == 1 { s[m] } else { (s[m - 1] + s[m]) / 2.0 };
        DistanceStats {
            count: d.len(),
            mean: d.iter().sum::<f64>() / n,
            median,
            rmse: (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
            max: s[s.len() - 1],
        }
    }
}

/// Planar / elevation errors of the matched pairs (predicted → nearest reference).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PositionErrors {
    #[serde(serialize_with = "finite_or_null")]
    pub mean_euclidean: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub mean_planar: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub mean_elevation: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub rmse_planar: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub rmse_elevation: f64,
    /// Mean of (pred z − ref z).
    #[serde(serialize_with = "finite_or_null")]
    pub mean_signed_dz: f64,
}

/// Reflectance error of one band pair.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandError {
    pub pred_band: String,
    pub ref_band: String,
    pub pred_center_nm: Option<f64>,
    pub ref_center_nm: Option<f64>,
    pub pairs: usize,
    #[serde(serialize_with = "finite_or_null")]
    pub mae: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub rmse: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub bias: f64,
}

/// Everything `compare-cloud` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompareReport {
    pub pred_points: usize,
    pub ref_points: usize,
    pub threshold: f64,
    /// pred → ref distances.
    pub accuracy: DistanceStats,
    /// ref → pred distances.
    pub completeness: DistanceStats,
    #[serde(serialize_with = "finite_or_null")]
    pub precision: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub recall: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub f_score: f64,
    pub position: PositionErrors,
    pub bands: Vec<BandError>,
    /// Why `bands` is empty, when it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub band_note: Option<String>,
}

/// Nearest neighbour in `tree` of every query point, on all cores: (index, distance). `order` (a permutation
/// of the queries, e.g. their own tree's leaf order) only sets the query order, for cache locality.
pub fn nearest_all(tree: &KdTree, queries: &[[f64; 3]], order: &[u32]) -> Vec<(usize, f64)> {
    let found = par_map(order, |&q| {
        tree.nearest(&queries[q as usize]).map(|(i, d2)| (i, d2.sqrt())).unwrap_or((usize::MAX, f64::INFINITY))
    });
    let mut out = vec![(usize::MAX, f64::INFINITY); queries.len()];
    for (&q, r) in order.iter().zip(found) {
        out[q as usize] = r;
    }
    out
}

fn pair_bands(pred: &PointCloud, reference: &PointCloud, tol: f64) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    for (i, pb) in pred.bands.iter().enumerate() {
        let j = match pb.center_nm {
            Some(c) => reference
                .bands
                .iter()
                .enumerate()
                .filter_map(|(j, rb)| rb.center_nm.map(|rc| (j, (rc - c).abs())))
                .filter(|&(_, d)| d <= tol)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| j),
            None => reference.bands.iter().position(|rb| rb.center_nm.is_none() && rb.name == pb.name),
        };
        if let Some(j) = j {
            pairs.push((i, j));
        }
    }
    pairs
}

/// Compares `pred` against `reference`.
pub fn compare_clouds(pred: &PointCloud, reference: &PointCloud, opts: &CompareOptions) -> Result<CompareReport> {
    if !(opts.threshold > 0.0 && opts.threshold.is_finite()) {
        return Err(OutputError::invalid("threshold", format!("must be positive, got {}", opts.threshold)));
    }
    pred.validate()?;
    reference.validate()?;
    if pred.is_empty() || reference.is_empty() {
        return Err(OutputError::invalid(
            "compare-cloud",
            format!("both clouds need points (pred {}, ref {})", pred.len(), reference.len()),
        ));
    }
    let ref_tree = KdTree::new(&reference.positions);
    let pred_tree = KdTree::new(&pred.positions);
    let p2r = nearest_all(&ref_tree, &pred.positions, pred_tree.leaf_order());
    let r2p = nearest_all(&pred_tree, &reference.positions, ref_tree.leaf_order());
    let acc: Vec<f64> = p2r.iter().map(|x| x.1).collect();
    let comp: Vec<f64> = r2p.iter().map(|x| x.1).collect();
    let t = opts.threshold;
    let precision = acc.iter().filter(|&&d| d < t).count() as f64 / acc.len() as f64;
    let recall = comp.iter().filter(|&&d| d < t).count() as f64 / comp.len() as f64;
    let f_score = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };

    let n = pred.len() as f64;
    let (mut planar, mut planar2, mut elev, mut elev2, mut dz_sum) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, &(j, _)) in p2r.iter().enumerate() {
        let (p, r) = (pred.positions[i], reference.positions[j]);
        let (dx, dy, dz) = (p[0] - r[0], p[1] - r[1], p[2] - r[2]);
        let pl2 = dx * dx + dy * dy;
        planar += pl2.sqrt();
        planar2 += pl2;
        elev += dz.abs();
        elev2 += dz * dz;
        dz_sum += dz;
    }
    let position = PositionErrors {
        mean_euclidean: acc.iter().sum::<f64>() / n,
        mean_planar: planar / n,
        mean_elevation: elev / n,
        rmse_planar: (planar2 / n).sqrt(),
        rmse_elevation: (elev2 / n).sqrt(),
        mean_signed_dz: dz_sum / n,
    };

    let mut band_note = None;
    let mut bands = Vec::new();
    if pred.n_bands() == 0 || reference.n_bands() == 0 {
        band_note = Some(format!(
            "no reflectance comparison: pred has {} bands, ref has {}",
            pred.n_bands(),
            reference.n_bands()
        ));
    } else {
        let pairs = pair_bands(pred, reference, opts.band_tolerance_nm);
        if pairs.is_empty() {
            band_note = Some("no reflectance comparison: no band of pred matches a band of ref".into());
        }
        for (pb, rb) in pairs {
            let (mut cnt, mut abs, mut sq, mut bias) = (0usize, 0.0, 0.0, 0.0);
            for (i, &(j, d)) in p2r.iter().enumerate() {
                if d >= t {
                    continue;
                }
                let (a, b) = (pred.point_values(i)[pb] as f64, reference.point_values(j)[rb] as f64);
                if !(a.is_finite() && b.is_finite()) {
                    continue;
                }
                let e = a - b;
                cnt += 1;
                abs += e.abs();
                sq += e * e;
                bias += e;
            }
            let c = cnt as f64;
            bands.push(BandError {
                pred_band: pred.bands[pb].name.clone(),
                ref_band: reference.bands[rb].name.clone(),
                pred_center_nm: pred.bands[pb].center_nm,
                ref_center_nm: reference.bands[rb].center_nm,
                pairs: cnt,
                mae: abs / c,
                rmse: (sq / c).sqrt(),
                bias: bias / c,
            });
        }
    }
    Ok(CompareReport {
        pred_points: pred.len(),
        ref_points: reference.len(),
        threshold: t,
        accuracy: DistanceStats::of(&acc),
        completeness: DistanceStats::of(&comp),
        precision,
        recall,
        f_score,
        position,
        bands,
        band_note,
    })
}

impl CompareReport {
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("CompareReport serialises: plain numbers and strings")
    }

    /// A short text table.
    pub fn table(&self) -> String {
        let f = |x: f64| if x.is_finite() { format!("{x:.4}") } else { "-".into() };
        let mut s =
            format!("pred {} points, ref {} points, threshold {}\n", self.pred_points, self.ref_points, self.threshold);
        s += &format!("{:<26} {:>10} {:>10} {:>10} {:>10}\n", "", "mean", "median", "rmse", "max");
        for (name, d) in [("accuracy (pred->ref)", &self.accuracy), ("completeness (ref->pred)", &self.completeness)] {
            s += &format!("{:<26} {:>10} {:>10} {:>10} {:>10}\n", name, f(d.mean), f(d.median), f(d.rmse), f(d.max));
        }
        s += &format!("precision {}  recall {}  F-score {}\n", f(self.precision), f(self.recall), f(self.f_score));
        let p = &self.position;
        s += &format!(
            "mean euclidean {}  mean planar {}  mean elevation {}  (signed dz {})\n",
            f(p.mean_euclidean),
            f(p.mean_planar),
            f(p.mean_elevation),
            f(p.mean_signed_dz)
        );
        if !self.bands.is_empty() {
            s += &format!("{:<24} {:>8} {:>10} {:>10} {:>10}\n", "band (pred/ref)", "pairs", "MAE", "RMSE", "bias");
            for b in &self.bands {
                let name = match b.pred_center_nm {
                    Some(c) => format!("{} {}nm", b.pred_band, fmt_nm(c)),
                    None => b.pred_band.clone(),
                };
                s += &format!("{:<24} {:>8} {:>10} {:>10} {:>10}\n", name, b.pairs, f(b.mae), f(b.rmse), f(b.bias));
            }
        }
        if let Some(n) = &self.band_note {
            s += n;
            s.push('\n');
        }
        s
    }
}
