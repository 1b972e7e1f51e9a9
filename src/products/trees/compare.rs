//! Trees found against trees known (the simulator's `truth/trees.geojson`, or a field inventory in the same table
//! layout): each known tree is matched to at most one found top within its crown radius (at least
//! [`MIN_MATCH_RADIUS`]), nearest pairs first; the heights of matched pairs are compared; a found top matched to no
//! known tree is a false tree, and with a class raster (1 = ground) a false tree standing on open ground is counted
//! apart.

use std::path::Path;

use serde_json::{json, Value};

use crate::output::raster::geotiff_read::GeoRaster;
use crate::output::{OutputError, Result};

/// Smallest radius (world units) within which a found top matches a known tree.
pub const MIN_MATCH_RADIUS: f64 = 1.0;

/// A tree of a table: id, position, height above the terrain, crown diameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreePoint {
    pub id: u64,
    pub x: f64,
    pub y: f64,
    pub height: f64,
    pub crown_diameter: f64,
}

/// The trees of a GeoJSON table written by [`super::table::write_geojson`] (point geometry; properties `id`,
/// `height_m`, `crown_diameter_m`); errors name the file and the feature.
pub fn read_tree_table(path: &Path) -> Result<Vec<TreePoint>> {
    let text = std::fs::read_to_string(path).map_err(|e| OutputError::read(path, e))?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| OutputError::read(path, format!("not JSON: {e}")))?;
    let features = doc["features"]
        .as_array()
        .ok_or_else(|| OutputError::read(path, "no `features` array: not a GeoJSON FeatureCollection"))?;
    features
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let bad = |what: &str| OutputError::read(path, format!("feature {i}: {what}"));
            let c = f["geometry"]["coordinates"].as_array().ok_or_else(|| bad("no point coordinates"))?;
            let num = |v: &Value, what: &str| v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| bad(what));
            let p = &f["properties"];
            Ok(TreePoint {
                id: p["id"].as_u64().or_else(|| f["id"].as_u64()).unwrap_or(i as u64 + 1),
                x: num(c.first().unwrap_or(&Value::Null), "x is not a number")?,
                y: num(c.get(1).unwrap_or(&Value::Null), "y is not a number")?,
                height: num(&p["height_m"], "`height_m` is not a number")?,
                crown_diameter: p["crown_diameter_m"].as_f64().filter(|x| x.is_finite()).unwrap_or(0.0),
            })
        })
        .collect()
}

/// One matched pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeMatch {
    pub truth: u64,
    pub found: u64,
    pub distance: f64,
    /// Found minus known height.
    pub height_error: f64,
}

/// The comparison (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct TreeComparison {
    pub known: usize,
    pub found: usize,
    pub matches: Vec<TreeMatch>,
    /// Ids of the known trees no top matched.
    pub missed: Vec<u64>,
    /// Ids of the found tops that matched no known tree.
    pub false_trees: Vec<u64>,
    /// Of those, the ones on open ground (None without a class raster).
    pub false_on_ground: Option<usize>,
    /// Height tolerance of [`TreeComparison::within`].
    pub tolerance: f64,
}

impl TreeComparison {
    /// Share of the known trees found with a height within `tolerance`.
    pub fn within(&self) -> f64 {
        let ok = self.matches.iter().filter(|m| m.height_error.abs() <= self.tolerance).count();
        if self.known == 0 {
            0.0
        } else {
            ok as f64 / self.known as f64
        }
    }

    pub fn median_abs_height_error(&self) -> f64 {
        let v: Vec<f64> = self.matches.iter().map(|m| m.height_error.abs()).collect();
        if v.is_empty() {
            f64::NAN
        } else {
            crate::util::stats::median(&v)
        }
    }

    pub fn mean_height_error(&self) -> f64 {
        self.matches.iter().map(|m| m.height_error).sum::<f64>() / self.matches.len().max(1) as f64
    }

    pub fn to_json(&self) -> Value {
        json!({
            "known": self.known,
            "found": self.found,
            "matched": self.matches.len(),
            "missed": self.missed,
            "false_trees": self.false_trees,
            "false_on_ground": self.false_on_ground,
            "height_tolerance": self.tolerance,
            "within_tolerance": self.within(),
            "median_abs_height_error": self.median_abs_height_error(),
            "mean_height_error": self.mean_height_error(),
            "matches": self.matches.iter().map(|m| json!({
                "truth": m.truth, "found": m.found, "distance": m.distance, "height_error": m.height_error
            })).collect::<Vec<_>>(),
        })
    }

    pub fn table(&self) -> String {
        let mut s = format!(
            "known trees {}, found {}, matched {}, missed {}, false {}{}\n",
            self.known,
            self.found,
            self.matches.len(),
            self.missed.len(),
            self.false_trees.len(),
            self.false_on_ground.map(|n| format!(" ({n} on open ground)")).unwrap_or_default()
        );
        s += &format!(
            "height: {:.1}% of known trees within {} (median |error| {:.3}, mean error {:+.3})\n",
            100.0 * self.within(),
            self.tolerance,
            self.median_abs_height_error(),
            self.mean_height_error()
        );
        s
    }
}

/// Compares `found` with `known` (see the module doc); `classes` (1 = ground) tells where a false tree stands.
pub fn compare_trees(
    found: &[TreePoint],
    known: &[TreePoint],
    classes: Option<&GeoRaster>,
    tolerance: f64,
) -> TreeComparison {
    let mut pairs = Vec::new();
    for (k, t) in known.iter().enumerate() {
        let radius = (0.5 * t.crown_diameter).max(MIN_MATCH_RADIUS);
        for (f, p) in found.iter().enumerate() {
            let d = (p.x - t.x).hypot(p.y - t.y);
            if d <= radius {
                pairs.push((d, k, f));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut k_used, mut f_used) = (vec![false; known.len()], vec![false; found.len()]);
    let mut matches = Vec::new();
    for (d, k, f) in pairs {
        if k_used[k] || f_used[f] {
            continue;
        }
        k_used[k] = true;
        f_used[f] = true;
        matches.push(TreeMatch {
            truth: known[k].id,
            found: found[f].id,
            distance: d,
            height_error: found[f].height - known[k].height,
        });
    }
    let missed = known.iter().zip(&k_used).filter(|(_, &u)| !u).map(|(t, _)| t.id).collect();
    let false_idx: Vec<usize> = (0..found.len()).filter(|&f| !f_used[f]).collect();
    let false_on_ground = classes.map(|c| {
        false_idx
            .iter()
            .filter(|&&f| c.grid.pixel_at(found[f].x, found[f].y).is_some_and(|(col, row)| c.value(0, col, row) == 1.0))
            .count()
    });
    TreeComparison {
        known: known.len(),
        found: found.len(),
        matches,
        missed,
        false_trees: false_idx.iter().map(|&f| found[f].id).collect(),
        false_on_ground,
        tolerance,
    }
}
