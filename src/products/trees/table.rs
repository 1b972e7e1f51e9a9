//! The tree table, written atomically as GeoJSON (a FeatureCollection of points in the rasters' CRS, named by the
//! GeoJSON 2008 `crs` member, which GDAL and QGIS read; RFC 7946 readers that assume WGS 84 must be told the CRS)
//! and as CSV (one row per tree, the same columns), both opened as layers by QGIS.
//!
//! Columns: `id`, `x`, `y`, `height_m` (above the terrain), `ground_z`, `top_z`, `crown_area_m2`,
//! `crown_diameter_m`, `ndvi`, `ndre` (empty when the bands do not allow them), `support` (the share of the crown the
//! DSM measured or interpolated; empty without its quality raster), `views` (training images that saw the top;
//! empty without the DSM's view counts), then `mean_<band>` for every band of the
//! orthomosaic. Units are the CRS's (metres in a projected CRS).

use std::path::Path;

use serde_json::{json, Map, Value};

use super::Tree;
use crate::output::{Band, OutputError, Result};

/// The fixed columns, in order ([`values`] gives one value for each: the array lengths must agree).
const FIXED: [&str; 12] = [
    "id",
    "x",
    "y",
    "height_m",
    "ground_z",
    "top_z",
    "crown_area_m2",
    "crown_diameter_m",
    "ndvi",
    "ndre",
    "support",
    "views",
];

/// The column names of [`write_csv`] for `bands`.
pub fn columns(bands: &[Band]) -> Vec<String> {
    FIXED.iter().map(|s| s.to_string()).chain(bands.iter().map(|b| format!("mean_{}", b.name))).collect()
}

fn values(t: &Tree) -> Vec<Option<f64>> {
    let f = |v: f64| v.is_finite().then_some(v);
    let fixed: [Option<f64>; FIXED.len()] = [
        Some(t.id as f64),
        f(t.x),
        f(t.y),
        f(t.height),
        f(t.ground_z),
        f(t.ground_z + t.height),
        f(t.crown_area),
        f(t.crown_diameter),
        t.ndvi,
        t.ndre,
        t.support,
        t.views,
    ];
    fixed.into_iter().chain(t.band_means.iter().map(|&m| f(m))).collect()
}

/// Rounded for the table: millimetres for positions and heights, 4 decimals for indices and reflectance.
fn fmt(col: &str, v: Option<f64>) -> String {
    match v {
        None => String::new(),
        Some(x) if col == "id" || col == "views" => format!("{}", x as u64),
        Some(x) if matches!(col, "x" | "y" | "height_m" | "ground_z" | "top_z" | "crown_diameter_m") => {
            format!("{x:.3}")
        }
        Some(x) if col == "crown_area_m2" => format!("{x:.2}"),
        Some(x) => format!("{x:.4}"),
    }
}

/// `trees` as CSV at `path` (atomically).
pub fn write_csv(path: &Path, trees: &[Tree], bands: &[Band]) -> Result<()> {
    let cols = columns(bands);
    let mut w = csv::Writer::from_writer(Vec::new());
    let bad = |e: csv::Error| OutputError::write(path, e);
    w.write_record(&cols).map_err(bad)?;
    for t in trees {
        let row: Vec<String> = cols.iter().zip(values(t)).map(|(c, v)| fmt(c, v)).collect();
        w.write_record(&row).map_err(bad)?;
    }
    let bytes = w.into_inner().map_err(|e| OutputError::write(path, e.error()))?;
    Ok(crate::util::atomic::write_bytes(path, &bytes)?)
}

/// `trees` as a GeoJSON FeatureCollection of points at `path` (atomically); `epsg` names the CRS.
pub fn write_geojson(path: &Path, trees: &[Tree], bands: &[Band], epsg: Option<u16>) -> Result<()> {
    let cols = columns(bands);
    let features: Vec<Value> = trees
        .iter()
        .map(|t| {
            let mut props = Map::new();
            for (c, v) in cols.iter().zip(values(t)) {
                if c == "x" || c == "y" {
                    continue;
                }
                let v = match v {
                    None => Value::Null,
                    Some(x) if c == "id" => json!(x as u64),
                    Some(_) => fmt(c, v).parse::<f64>().map(|x| json!(x)).unwrap_or(Value::Null),
                };
                props.insert(c.clone(), v);
            }
            let top = t.ground_z + t.height;
            let coords = if top.is_finite() { json!([t.x, t.y, top]) } else { json!([t.x, t.y]) };
            let geometry = json!({"type": "Point", "coordinates": coords});
            json!({"type": "Feature", "id": t.id, "geometry": geometry, "properties": props})
        })
        .collect();
    let mut doc = json!({"type": "FeatureCollection", "name": "trees", "features": features});
    if let Some(e) = epsg {
        doc["crs"] = json!({"type": "name", "properties": {"name": format!("urn:ogc:def:crs:EPSG::{e}")}});
    }
    let text = serde_json::to_string_pretty(&doc).map_err(|e| OutputError::write(path, e))?;
    Ok(crate::util::atomic::write_bytes(path, text.as_bytes())?)
}
