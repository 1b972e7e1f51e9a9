//! Raster-to-raster comparison (`msnerf compare-raster`): a DSM or orthomosaic against a reference on any north-up
//! grid in the same CRS (a LiDAR DSM, the simulator's `truth/dsm.tif` and `truth/ortho.tif`).
//!
//! Every valid predicted cell is compared with the reference cell that contains its centre (nearest-neighbour, as
//! QGIS's raster calculator does on aligned grids). Per band: signed bias (mean of pred - ref), median signed and
//! absolute error, RMSE, the fraction within each tolerance and, with a `peak`, PSNR = 10 log10(peak² / MSE).
//! Completeness is the fraction of valid reference cells under the prediction's grid that the prediction covers.
//!
//! With a class raster (integer codes, band named like `classes 1=ground 2=roof 3=object`), the same statistics per
//! class over **interior** cells only: cells whose 3 x 3 neighbourhood in the class raster is one class, so that a
//! footprint-sized misplacement of an edge does not count as a height error there (edges are judged separately).
//!
//! With the prediction's own quality raster (a DSM's `_quality.tif`, on the prediction's grid), the same statistics
//! per quality code over every cell: how far the cells labelled measured, interpolated or field only lie from the
//! reference.

use serde::Serialize;

use super::raster::geotiff_read::GeoRaster;
use super::{OutputError, Result};

/// Error statistics of one band over a set of cells.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct BandErrors {
    pub band: String,
    pub cells: usize,
    pub bias: f64,
    pub median: f64,
    pub median_abs: f64,
    pub rmse: f64,
    /// (tolerance, fraction of cells with |error| <= tolerance)
    pub within: Vec<(f64, f64)>,
    pub psnr_db: Option<f64>,
}

/// Statistics of one class (interior cells).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ClassErrors {
    pub code: i64,
    pub name: String,
    pub bands: Vec<BandErrors>,
}

/// The prediction's quality raster (same grid) and the names of its codes.
pub struct QualityLayer<'a> {
    pub raster: &'a GeoRaster,
    pub names: Vec<(i64, String)>,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RasterCompareReport {
    /// Valid predicted cells.
    pub pred_cells: usize,
    /// Valid reference cells under the prediction's grid.
    pub ref_cells: usize,
    /// Cells valid in both.
    pub compared: usize,
    /// compared / ref_cells.
    pub completeness: f64,
    pub bands: Vec<BandErrors>,
    pub classes: Vec<ClassErrors>,
    /// Per code of the prediction's quality raster, every cell (empty without one).
    pub quality: Vec<ClassErrors>,
}

/// Options of [`compare_rasters`].
#[derive(Debug, Clone, Default)]
pub struct RasterCompareOptions {
    pub within: Vec<f64>,
    /// Peak value for PSNR (1 for reflectance); None: no PSNR.
    pub peak: Option<f64>,
}

/// Class codes and names from a class band's name (`classes 1=ground 2=roof`).
pub fn class_names(desc: &str) -> Vec<(i64, String)> {
    desc.split_whitespace()
        .filter_map(|t| t.split_once('='))
        .filter_map(|(k, v)| k.parse().ok().map(|k| (k, v.to_string())))
        .collect()
}

fn errors(band: &str, d: &mut [f64], opts: &RasterCompareOptions) -> BandErrors {
    let n = d.len();
    if n == 0 {
        return BandErrors {
            band: band.into(),
            cells: 0,
            bias: f64::NAN,
            median: f64::NAN,
            median_abs: f64::NAN,
            rmse: f64::NAN,
            within: opts.within.iter().map(|&t| (t, f64::NAN)).collect(),
            psnr_db: None,
        };
    }
    let bias = d.iter().sum::<f64>() / n as f64;
    let mse = d.iter().map(|v| v * v).sum::<f64>() / n as f64;
    let median = crate::util::stats::median(d);
    let mut abs: Vec<f64> = d.iter().map(|v| v.abs()).collect();
    let median_abs = crate::util::stats::median(&abs);
    abs.sort_by(f64::total_cmp);
    let within = opts.within.iter().map(|&t| (t, abs.partition_point(|&v| v <= t) as f64 / n as f64)).collect();
    BandErrors {
        band: band.into(),
        cells: n,
        bias,
        median,
        median_abs,
        rmse: mse.sqrt(),
        within,
        psnr_db: opts.peak.map(|p| 10.0 * (p * p / mse).log10()),
    }
}

/// Compares `pred` with `reference` (and per class of `classes`); both must have the same number of bands and,
/// when both name one, the same EPSG code.
pub fn compare_rasters(
    pred: &GeoRaster,
    reference: &GeoRaster,
    classes: Option<&GeoRaster>,
    quality: Option<&QualityLayer>,
    opts: &RasterCompareOptions,
) -> Result<RasterCompareReport> {
    let (p, r) = (&pred.grid, &reference.grid);
    if let Some(q) = quality {
        if (q.raster.grid.width, q.raster.grid.height) != (p.width, p.height) {
            return Err(OutputError::invalid(
                "--quality",
                format!(
                    "{} x {} cells against the prediction's {} x {}: not its quality raster",
                    q.raster.grid.width, q.raster.grid.height, p.width, p.height
                ),
            ));
        }
    }
    let quality_names: &[(i64, String)] = quality.map_or(&[], |q| &q.names);
    let mut per_quality: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); p.bands]; quality_names.len()];
    if p.bands != r.bands {
        return Err(OutputError::invalid("--ref", format!("{} bands against the prediction's {}", r.bands, p.bands)));
    }
    if let (Some(a), Some(b)) = (p.epsg, r.epsg) {
        if a != b {
            return Err(OutputError::invalid("--ref", format!("EPSG:{b} against the prediction's EPSG:{a}")));
        }
    }
    let nb = p.bands;
    let names: Vec<(i64, String)> =
        classes.map(|c| class_names(c.grid.descriptions.first().map_or("", |s| s.as_str()))).unwrap_or_default();
    let class_at = |x: f64, y: f64| -> Option<i64> {
        let c = classes?;
        let (col, row) = c.grid.pixel_at(x, y)?;
        if col == 0 || row == 0 || col + 1 >= c.grid.width || row + 1 >= c.grid.height {
            return None;
        }
        let k = c.value(0, col, row);
        let same = (-1i64..=1)
            .all(|dy| (-1i64..=1).all(|dx| c.value(0, (col as i64 + dx) as usize, (row as i64 + dy) as usize) == k));
        (same && k.is_finite()).then_some(k as i64)
    };
    let mut d: Vec<Vec<f64>> = vec![Vec::new(); nb];
    let mut per_class: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); nb]; names.len()];
    let (mut pred_cells, mut ref_cells, mut compared) = (0, 0, 0);
    for row in 0..p.height {
        for col in 0..p.width {
            let [x, y] = p.centre(col, row);
            let pv: Vec<f32> = (0..nb).map(|b| pred.value(b, col, row)).collect();
            let p_ok = pv.iter().all(|&v| !pred.is_nodata(v));
            pred_cells += usize::from(p_ok);
            let Some((rc, rr)) = r.pixel_at(x, y) else { continue };
            let rv: Vec<f32> = (0..nb).map(|b| reference.value(b, rc, rr)).collect();
            if rv.iter().any(|&v| reference.is_nodata(v)) {
                continue;
            }
            ref_cells += 1;
            if !p_ok {
                continue;
            }
            compared += 1;
            let k = class_at(x, y).and_then(|k| names.iter().position(|(c, _)| *c == k));
            let qk = quality.and_then(|q| {
                let v = q.raster.value(0, col, row);
                quality_names.iter().position(|(c, _)| v.is_finite() && *c == v as i64)
            });
            for b in 0..nb {
                let e = pv[b] as f64 - rv[b] as f64;
                d[b].push(e);
                if let Some(i) = k {
                    per_class[i][b].push(e);
                }
                if let Some(i) = qk {
                    per_quality[i][b].push(e);
                }
            }
        }
    }
    if compared == 0 {
        // No cell with values in both: the rasters do not overlap, or one is nodata where the other has data.
        // Statistics over nothing would be NaN; say why instead.
        return Err(OutputError::invalid(
            "--ref",
            format!(
                "no cell to compare: {pred_cells} predicted cells with data, {ref_cells} reference cells with data \
                 under the prediction's grid (do the rasters overlap, in one CRS?)"
            ),
        ));
    }
    let band_name =
        |b: usize| p.descriptions.get(b).filter(|s| !s.is_empty()).cloned().unwrap_or(format!("band {}", b + 1));
    let bands = (0..nb).map(|b| errors(&band_name(b), &mut d[b], opts)).collect();
    let groups = |names: &[(i64, String)], per: &mut [Vec<Vec<f64>>]| -> Vec<ClassErrors> {
        names
            .iter()
            .zip(per.iter_mut())
            .map(|((code, name), dd)| ClassErrors {
                code: *code,
                name: name.clone(),
                bands: (0..nb).map(|b| errors(&band_name(b), &mut dd[b], opts)).collect(),
            })
            .collect()
    };
    let classes = groups(&names, &mut per_class);
    let quality = groups(quality_names, &mut per_quality);
    Ok(RasterCompareReport {
        pred_cells,
        ref_cells,
        compared,
        completeness: if ref_cells > 0 { compared as f64 / ref_cells as f64 } else { f64::NAN },
        bands,
        classes,
        quality,
    })
}

impl RasterCompareReport {
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("serialisable")
    }

    /// A plain-text table: one line per band, then per class and band.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{} predicted cells, {} reference cells under them, {} compared (completeness {:.1} %)\n",
            self.pred_cells,
            self.ref_cells,
            self.compared,
            100.0 * self.completeness
        );
        let line = |s: &mut String, who: &str, e: &BandErrors| {
            let within: Vec<String> = e.within.iter().map(|(t, f)| format!("<={t}: {:.1} %", 100.0 * f)).collect();
            let psnr = e.psnr_db.map(|p| format!(", PSNR {p:.2} dB")).unwrap_or_default();
            *s += &format!(
                "{who}{}: {} cells, bias {:+.4}, median {:+.4}, median |e| {:.4}, RMSE {:.4}{psnr}; {}\n",
                e.band,
                e.cells,
                e.bias,
                e.median,
                e.median_abs,
                e.rmse,
                within.join(", ")
            );
        };
        for e in &self.bands {
            line(&mut s, "", e);
        }
        // A class the band names but no interior cell carries (e.g. the simulator's horizon) gets no lines of its
        // own, only a mention; the JSON keeps it with 0 cells.
        let (present, absent): (Vec<&ClassErrors>, Vec<&ClassErrors>) =
            self.classes.iter().partition(|c| c.bands.iter().any(|e| e.cells > 0));
        for c in present {
            for e in &c.bands {
                line(&mut s, &format!("[{} interior] ", c.name), e);
            }
        }
        if !absent.is_empty() {
            let names: Vec<&str> = absent.iter().map(|c| c.name.as_str()).collect();
            s += &format!("classes without interior cells: {}\n", names.join(", "));
        }
        for c in self.quality.iter().filter(|c| c.bands.iter().any(|e| e.cells > 0)) {
            for e in &c.bands {
                line(&mut s, &format!("[{}] ", c.name), e);
            }
        }
        s
    }
}
