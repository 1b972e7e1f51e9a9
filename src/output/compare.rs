//! Cloud-to-cloud comparison (`msnerf compare-cloud --pred A --ref B`).
//!
//! - **Distances** go from a point to the other cloud's surface: by default to the least-squares plane of its 6
//!   nearest points where that plane applies, else to the nearest point (CloudCompare's C2C with a local model,
//!   [`DistanceModel`], `--local-model plane|none`; see [`local_plane`](super::pointcloud::local_plane) for why
//!   and for the guards). A point's offset vector (point minus its foot on the surface) gives the planar and
//!   elevation parts below.
//! - **Accuracy**: distance from each predicted point to the reference (mean, median, RMSE, max).
//! - **Completeness**: the same from each reference point to the prediction.
//! - **Precision / recall / F-score** at a distance threshold τ (default 0.1 m): the fraction of predicted
//!   (reference) points whose nearest neighbour in the other cloud is closer than τ, and `2PR/(P+R)` (Tanks and
//!   Temples' definition, strict `<`).
//! - **Fractions within thresholds** (`--within 0.1,0.25,0.5,1.0`, [`DEFAULT_WITHIN`]): for each threshold t, the
//!   fraction of predicted points closer than t to the reference (accuracy side) and of reference points closer
//!   than t to the prediction (completeness side); strict `<`, as for precision and recall, so the fractions at
//!   t = τ are the precision and the recall ([`WithinFraction`]).
//! - **Planar and elevation errors** of the matched pairs (every predicted point and its foot on the reference,
//!   or its nearest reference point), as the paper's Tables 6–7 report them: the Euclidean distance `ED`, the planar
//!   distance `√(dx² + dy²)` and the elevation distance `|dz|` (z up), averaged; their medians and RMSEs; and the
//!   signed elevation bias dz = pred z − ref z, as a mean and a median ([`PositionErrors`]).
//! - **Verdict against an accuracy standard** (`--standard planar=0.3,vertical=0.5`, [`AccuracyStandard`];
//!   the default is the one the Multispectral-NeRF paper cites: planar < 0.3 m, vertical < 0.5 m). Like the
//!   ASPRS positional accuracy standards, the standard is stated as an RMSE: the planar RMSE
//!   `√(mean(dx² + dy²))` (ASPRS's RMSE_r = `√(RMSE_x² + RMSE_y²)`) and the vertical RMSE `√(mean(dz²))`
//!   (RMSE_z) over the matched pairs are compared with the limits; an axis passes when its RMSE is at most its
//!   limit, and the cloud passes when both axes do ([`StandardVerdict`]).
//! - **Per-band reflectance error** (MAE, RMSE, bias = mean(pred − ref)) over the matched pairs closer than τ,
//!   when both clouds carry bands; bands are paired by centre wavelength (nearest within 25 nm), or by equal
//!   name when centres are missing.
//!
//! [`compare_clouds`] uses the default thresholds and standard; [`compare_clouds_with`] takes them
//! ([`AccuracyOptions`]). [`parse_within`] and [`AccuracyStandard::parse`] read the command-line forms and
//! name the flag and the offending item in their errors.
//!
//! Nearest neighbours come from [`KdTree`] (exact f64); queries run on all cores.

use serde::Serialize;

use super::image::fmt_nm;
use super::metrics::report::finite_or_null;
use super::pointcloud::filter::par_map;
use super::pointcloud::kdtree::KdTree;
use super::pointcloud::local_plane::{surface_offset, SurfaceOffset};
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

/// Default thresholds (metres) of the within-threshold fractions (`--within`).
pub const DEFAULT_WITHIN: [f64; 4] = [0.1, 0.25, 0.5, 1.0];

/// A positional accuracy standard, stated as RMSEs of the matched pairs (as the ASPRS standards are): the
/// planar RMSE `√(mean(dx² + dy²))` (ASPRS's RMSE_r) and the vertical RMSE `√(mean(dz²))` (RMSE_z), in the
/// clouds' unit (metres). An axis passes when its RMSE is at most its limit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AccuracyStandard {
    /// Largest planar RMSE.
    pub planar: f64,
    /// Largest vertical (elevation) RMSE.
    pub vertical: f64,
}

impl AccuracyStandard {
    /// The accuracy the Multispectral-NeRF paper cites: planar < 0.3 m, vertical < 0.5 m.
    pub const MULTISPECTRAL_NERF: AccuracyStandard = AccuracyStandard { planar: 0.3, vertical: 0.5 };

    /// Parses the `--standard` form `planar=0.3,vertical=0.5` (metres; spaces around items are ignored). A key
    /// left out keeps its [`AccuracyStandard::MULTISPECTRAL_NERF`] value. Unknown or repeated keys, items
    /// without `=`, values that are not numbers and values that are not positive and finite are errors naming
    /// `--standard` and the offending item.
    pub fn parse(s: &str) -> Result<AccuracyStandard> {
        let err = |reason: String| OutputError::invalid("--standard", reason);
        if s.trim().is_empty() {
            return Err(err("empty; expected e.g. `planar=0.3,vertical=0.5`".into()));
        }
        let mut out = AccuracyStandard::MULTISPECTRAL_NERF;
        let (mut seen_planar, mut seen_vertical) = (false, false);
        for item in s.split(',').map(str::trim) {
            let Some((key, value)) = item.split_once('=') else {
                return Err(err(format!("`{item}` is not key=value (keys: planar, vertical)")));
            };
            let (slot, seen) = match key.trim() {
                "planar" => (&mut out.planar, &mut seen_planar),
                "vertical" => (&mut out.vertical, &mut seen_vertical),
                _ => return Err(err(format!("unknown key in `{item}` (keys: planar, vertical)"))),
            };
            if *seen {
                return Err(err(format!("`{item}`: `{}` is given twice", key.trim())));
            }
            *seen = true;
            let v: f64 = value.trim().parse().map_err(|_| err(format!("`{item}` is not a number")))?;
            if !(v > 0.0 && v.is_finite()) {
                return Err(err(format!("`{item}` must be a positive, finite number of metres")));
            }
            *slot = v;
        }
        Ok(out)
    }

    /// Judges the RMSEs of `position` against this standard.
    pub fn judge(&self, position: &PositionErrors) -> StandardVerdict {
        let axis = |rmse: f64, limit: f64| AxisVerdict { rmse, limit, pass: rmse <= limit };
        let planar = axis(position.rmse_planar, self.planar);
        let vertical = axis(position.rmse_elevation, self.vertical);
        StandardVerdict { statistic: STANDARD_STATISTIC, planar, vertical, pass: planar.pass && vertical.pass }
    }

    fn check(&self) -> Result<()> {
        for (name, v) in [("planar", self.planar), ("vertical", self.vertical)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(OutputError::invalid(
                    "--standard",
                    format!("`{name}={v}` must be a positive, finite number of metres"),
                ));
            }
        }
        Ok(())
    }
}

impl Default for AccuracyStandard {
    fn default() -> Self {
        AccuracyStandard::MULTISPECTRAL_NERF
    }
}

/// What [`StandardVerdict`] compares, in words (it goes into the JSON).
pub const STANDARD_STATISTIC: &str = "RMSE over the matched pairs (each predicted point and its nearest \
    reference point): planar sqrt(mean(dx^2 + dy^2)), vertical sqrt(mean(dz^2)); an axis passes when RMSE <= limit";

/// Parses the `--within` form `0.1,0.25,0.5,1.0` (metres, kept in the given order). Empty lists, items that are
/// not numbers and values that are not positive and finite are errors naming `--within` and the item.
pub fn parse_within(s: &str) -> Result<Vec<f64>> {
    let err = |reason: String| OutputError::invalid("--within", reason);
    if s.trim().is_empty() {
        return Err(err("empty; expected e.g. `0.1,0.25,0.5,1.0`".into()));
    }
    s.split(',')
        .map(str::trim)
        .map(|item| {
            let v: f64 = item.parse().map_err(|_| err(format!("`{item}` is not a number")))?;
            if !(v > 0.0 && v.is_finite()) {
                return Err(err(format!("`{item}` must be a positive, finite distance")));
            }
            Ok(v)
        })
        .collect()
}

/// How the distance from a point to the other cloud is measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DistanceModel {
    /// To the nearest point (plain cloud-to-cloud): never zero between the other cloud's samples.
    Nearest,
    /// To the least-squares plane of the `k` nearest points, where it applies ([`local_plane`](
    /// super::pointcloud::local_plane)); CloudCompare's C2C with a local model. The default, with k = 6.
    Plane { k: usize },
}

impl DistanceModel {
    /// CloudCompare's default neighbourhood for the local model.
    pub const DEFAULT_PLANE: DistanceModel = DistanceModel::Plane { k: 6 };

    /// Parses `--local-model`: `plane` (with `k` neighbours) or `none`.
    pub fn parse(s: &str, k: usize) -> Result<DistanceModel> {
        match s.trim() {
            "plane" if k >= 3 => Ok(DistanceModel::Plane { k }),
            "plane" => Err(OutputError::invalid("--local-k", format!("{k}: a plane needs at least 3 neighbours"))),
            "none" => Ok(DistanceModel::Nearest),
            other => Err(OutputError::invalid("--local-model", format!("`{other}`: expected `plane` or `none`"))),
        }
    }

    fn k(&self) -> usize {
        match *self {
            DistanceModel::Nearest => 1,
            DistanceModel::Plane { k } => k,
        }
    }

    /// In words, for tables.
    pub fn describe(&self) -> String {
        match self {
            DistanceModel::Nearest => "nearest point".into(),
            DistanceModel::Plane { k } => format!("local least-squares plane of {k} points"),
        }
    }
}

/// The within-threshold fractions, the accuracy standard and the distance model of a comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct AccuracyOptions {
    /// Thresholds of the within-threshold fractions, in the clouds' unit.
    pub within: Vec<f64>,
    /// The standard the verdict is judged against.
    pub standard: AccuracyStandard,
    /// How a point's distance to the other cloud is measured (both directions).
    pub model: DistanceModel,
}

impl Default for AccuracyOptions {
    fn default() -> Self {
        AccuracyOptions {
            within: DEFAULT_WITHIN.to_vec(),
            standard: AccuracyStandard::default(),
            model: DistanceModel::DEFAULT_PLANE,
        }
    }
}

/// Fractions of points closer than `threshold` (strict `<`) to the other cloud.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WithinFraction {
    pub threshold: f64,
    /// Accuracy side: predicted points whose nearest reference point is closer than `threshold`.
    pub pred_fraction: f64,
    /// Completeness side: reference points whose nearest predicted point is closer than `threshold`.
    pub ref_fraction: f64,
}

/// One axis of a [`StandardVerdict`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisVerdict {
    /// The measured RMSE of the matched pairs.
    #[serde(serialize_with = "finite_or_null")]
    pub rmse: f64,
    /// The standard's largest RMSE.
    pub limit: f64,
    /// `rmse <= limit`.
    pub pass: bool,
}

/// The comparison judged against an [`AccuracyStandard`]: per axis and overall.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StandardVerdict {
    /// What is compared ([`STANDARD_STATISTIC`]).
    pub statistic: &'static str,
    pub planar: AxisVerdict,
    pub vertical: AxisVerdict,
    /// Both axes pass.
    pub pass: bool,
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
        let s = sorted(d);
        DistanceStats {
            count: d.len(),
            mean: d.iter().sum::<f64>() / n,
            median: median_of_sorted(&s),
            rmse: (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
            max: s[s.len() - 1],
        }
    }
}

fn sorted(d: &[f64]) -> Vec<f64> {
    let mut s = d.to_vec();
    s.sort_unstable_by(|a, b| a.total_cmp(b));
    s
}

pub use crate::util::stats::{median, median_of_sorted};

/// Planar / elevation errors of the matched pairs (every predicted point and its nearest reference point):
/// planar = `√(dx² + dy²)`, elevation = `|dz|`, signed dz = pred z − ref z.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PositionErrors {
    #[serde(serialize_with = "finite_or_null")]
    pub mean_euclidean: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub mean_planar: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub mean_elevation: f64,
    #[serde(serialize_with = "finite_or_null")]
    pub median_planar: f64,
    /// Median of |dz|.
    #[serde(serialize_with = "finite_or_null")]
    pub median_elevation: f64,
    /// `√(mean(dx² + dy²))` (ASPRS's RMSE_r).
    #[serde(serialize_with = "finite_or_null")]
    pub rmse_planar: f64,
    /// `√(mean(dz²))` (ASPRS's RMSE_z).
    #[serde(serialize_with = "finite_or_null")]
    pub rmse_elevation: f64,
    /// Mean of (pred z − ref z): the vertical bias.
    #[serde(serialize_with = "finite_or_null")]
    pub mean_signed_dz: f64,
    /// Median of (pred z − ref z): the vertical bias, robust to floaters.
    #[serde(serialize_with = "finite_or_null")]
    pub median_signed_dz: f64,
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
    /// How distances are measured ([`DistanceModel`]).
    pub distance_model: DistanceModel,
    /// Fraction of predicted points whose distance came from the local plane (the rest: the nearest point).
    #[serde(serialize_with = "finite_or_null")]
    pub plane_fraction: f64,
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
    /// Fractions of points within each `--within` threshold, in the given order.
    pub within: Vec<WithinFraction>,
    /// The matched pairs' RMSEs judged against the accuracy standard.
    pub standard: StandardVerdict,
    pub bands: Vec<BandError>,
    /// Why `bands` is empty, when it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub band_note: Option<String>,
}

/// Every query's offset from the surface `tree` samples (`points`), under `model`, on all cores. `order` (a
/// permutation of the queries, e.g. their own tree's leaf order) only sets the query order, for cache locality.
pub fn surface_offsets_all(
    tree: &KdTree,
    points: &[[f64; 3]],
    queries: &[[f64; 3]],
    order: &[u32],
    model: DistanceModel,
) -> Vec<SurfaceOffset> {
    let found = par_map(order, |&q| surface_offset(tree, points, &queries[q as usize], model.k()).unwrap_or_default());
    let mut out = vec![SurfaceOffset::default(); queries.len()];
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

/// Compares `pred` against `reference` with the default within-thresholds ([`DEFAULT_WITHIN`]) and standard
/// ([`AccuracyStandard::MULTISPECTRAL_NERF`]).
pub fn compare_clouds(pred: &PointCloud, reference: &PointCloud, opts: &CompareOptions) -> Result<CompareReport> {
    compare_clouds_with(pred, reference, opts, &AccuracyOptions::default())
}

/// Compares `pred` against `reference`, with the within-threshold fractions and the standard of `accuracy`.
pub fn compare_clouds_with(
    pred: &PointCloud,
    reference: &PointCloud,
    opts: &CompareOptions,
    accuracy: &AccuracyOptions,
) -> Result<CompareReport> {
    if !(opts.threshold > 0.0 && opts.threshold.is_finite()) {
        return Err(OutputError::invalid("threshold", format!("must be positive, got {}", opts.threshold)));
    }
    if accuracy.within.is_empty() {
        return Err(OutputError::invalid("--within", "needs at least one threshold"));
    }
    if let Some(&t) = accuracy.within.iter().find(|t| !(**t > 0.0 && t.is_finite())) {
        return Err(OutputError::invalid("--within", format!("`{t}` must be a positive, finite distance")));
    }
    accuracy.standard.check()?;
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
    let m = accuracy.model;
    let p2r_off = surface_offsets_all(&ref_tree, &reference.positions, &pred.positions, pred_tree.leaf_order(), m);
    let r2p_off = surface_offsets_all(&pred_tree, &pred.positions, &reference.positions, ref_tree.leaf_order(), m);
    let p2r: Vec<(usize, f64)> = p2r_off.iter().map(|o| (o.nearest, o.distance())).collect();
    let acc: Vec<f64> = p2r.iter().map(|x| x.1).collect();
    let comp: Vec<f64> = r2p_off.iter().map(|o| o.distance()).collect();
    let t = opts.threshold;
    let precision = acc.iter().filter(|&&d| d < t).count() as f64 / acc.len() as f64;
    let recall = comp.iter().filter(|&&d| d < t).count() as f64 / comp.len() as f64;
    let f_score = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };

    let within = accuracy
        .within
        .iter()
        .map(|&t| WithinFraction {
            threshold: t,
            pred_fraction: acc.iter().filter(|&&d| d < t).count() as f64 / acc.len() as f64,
            ref_fraction: comp.iter().filter(|&&d| d < t).count() as f64 / comp.len() as f64,
        })
        .collect();

    let n = pred.len() as f64;
    let (mut planar, mut planar2, mut elev, mut elev2, mut dz_sum) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut planar_d = Vec::with_capacity(pred.len());
    let mut signed_dz = Vec::with_capacity(pred.len());
    for o in &p2r_off {
        let [dx, dy, dz] = o.offset;
        let pl2 = dx * dx + dy * dy;
        planar += pl2.sqrt();
        planar2 += pl2;
        elev += dz.abs();
        elev2 += dz * dz;
        dz_sum += dz;
        planar_d.push(pl2.sqrt());
        signed_dz.push(dz);
    }
    let abs_dz: Vec<f64> = signed_dz.iter().map(|d| d.abs()).collect();
    let position = PositionErrors {
        mean_euclidean: acc.iter().sum::<f64>() / n,
        mean_planar: planar / n,
        mean_elevation: elev / n,
        median_planar: median(&planar_d),
        median_elevation: median(&abs_dz),
        rmse_planar: (planar2 / n).sqrt(),
        rmse_elevation: (elev2 / n).sqrt(),
        mean_signed_dz: dz_sum / n,
        median_signed_dz: median(&signed_dz),
    };
    let standard = accuracy.standard.judge(&position);

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
        distance_model: m,
        plane_fraction: p2r_off.iter().filter(|o| o.plane).count() as f64 / n,
        accuracy: DistanceStats::of(&acc),
        completeness: DistanceStats::of(&comp),
        precision,
        recall,
        f_score,
        position,
        within,
        standard,
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
        s += &format!(
            "distance to the other cloud: {} ({:.0} % of pred points by the plane)\n",
            self.distance_model.describe(),
            100.0 * self.plane_fraction
        );
        s += &format!("{:<26} {:>10} {:>10} {:>10} {:>10}\n", "", "mean", "median", "rmse", "max");
        for (name, d) in [("accuracy (pred->ref)", &self.accuracy), ("completeness (ref->pred)", &self.completeness)] {
            s += &format!("{:<26} {:>10} {:>10} {:>10} {:>10}\n", name, f(d.mean), f(d.median), f(d.rmse), f(d.max));
        }
        s += &format!("precision {}  recall {}  F-score {}\n", f(self.precision), f(self.recall), f(self.f_score));
        s += &format!("{:<26} {:>20} {:>20}\n", "fraction within", "pred (accuracy)", "ref (completeness)");
        for w in &self.within {
            s +=
                &format!("{:<26} {:>20} {:>20}\n", format!("< {}", w.threshold), f(w.pred_fraction), f(w.ref_fraction));
        }
        let p = &self.position;
        s += &format!("{:<26} {:>10} {:>10} {:>10}\n", "matched pairs (pred->ref)", "mean", "median", "rmse");
        let a = &self.accuracy;
        for (name, mean, median, rmse) in [
            ("euclidean", p.mean_euclidean, a.median, a.rmse),
            ("planar", p.mean_planar, p.median_planar, p.rmse_planar),
            ("elevation |dz|", p.mean_elevation, p.median_elevation, p.rmse_elevation),
            ("signed dz (pred-ref)", p.mean_signed_dz, p.median_signed_dz, f64::NAN),
        ] {
            s += &format!("{:<26} {:>10} {:>10} {:>10}\n", name, f(mean), f(median), f(rmse));
        }
        let v = &self.standard;
        let word = |pass: bool| if pass { "pass" } else { "FAIL" };
        s += "accuracy standard: RMSE of the matched pairs, pass when RMSE <= limit\n";
        s += &format!("{:<26} {:>10} {:>10} {:>10}\n", "", "rmse", "limit", "verdict");
        for (name, x) in [("planar", &v.planar), ("vertical", &v.vertical)] {
            s += &format!("{:<26} {:>10} {:>10} {:>10}\n", name, f(x.rmse), x.limit, word(x.pass));
        }
        s += &format!("{:<26} {:>10} {:>10} {:>10}\n", "overall", "", "", word(v.pass));
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
