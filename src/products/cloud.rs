//! The multispectral point cloud after the field's export (`nerf::export`): the careful export's filters from
//! their settings, the post-filters an MVS pipeline runs (crop, statistical outlier removal, one point per grid cube,
//! a point budget), writing as PLY or LAS with the dataset's CRS, and the one-line summaries the commands print.
//! [`CloudFilter::default`] is the single source of the post-filters' defaults (`export pointcloud`'s flags,
//! `process` and `demo` take them from here).

use std::path::Path;

use super::ProductError;
use crate::geo::Crs;
use crate::nerf::export::{Consistency, ExportStats};
use crate::output::pointcloud::{self, LasOptions, PlyOptions, PointCloud};

/// The post-filters of a cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudFilter {
    /// Axis-aligned crop box in world units: min x, y, z, max x, y, z.
    pub crop: Option<[f64; 6]>,
    /// Statistical outlier removal: neighbours (0: off) and the standard-deviation ratio.
    pub outlier_neighbours: usize,
    pub outlier_std_ratio: f64,
    /// One point per cube of this edge (world units): the most consistent, then the least spread.
    pub gsd: Option<f64>,
    /// At most this many points (random, seeded subsample).
    pub points: Option<usize>,
    pub seed: u64,
}

impl Default for CloudFilter {
    fn default() -> Self {
        CloudFilter { crop: None, outlier_neighbours: 20, outlier_std_ratio: 10.0, gsd: None, points: None, seed: 42 }
    }
}

impl CloudFilter {
    /// Checks the settings; errors name the option.
    pub fn validate(&self) -> Result<(), ProductError> {
        if let Some(b) = &self.crop {
            if !(b.iter().all(|v| v.is_finite()) && (0..3).all(|k| b[k] < b[k + 3])) {
                return Err(ProductError::option(
                    "--crop",
                    format!("needs minx,miny,minz,maxx,maxy,maxz with each min below its max, got {b:?}"),
                ));
            }
        }
        if !(self.outlier_std_ratio.is_finite() && self.outlier_std_ratio > 0.0) {
            return Err(ProductError::option(
                "--outlier-std-ratio",
                format!("must be > 0, got {}", self.outlier_std_ratio),
            ));
        }
        if let Some(g) = self.gsd {
            if !(g.is_finite() && g > 0.0) {
                return Err(ProductError::option("--gsd", format!("must be > 0, got {g}")));
            }
        }
        Ok(())
    }

    /// Applies the filters in order: crop, outliers, thinning, budget.
    pub fn apply(&self, mut cloud: PointCloud) -> Result<PointCloud, ProductError> {
        if let Some(b) = &self.crop {
            let inside = |p: &[f64; 3]| (0..3).all(|k| p[k] >= b[k] && p[k] <= b[k + 3]);
            cloud = pointcloud::filter::crop(&cloud, inside)?.0;
        }
        if self.outlier_neighbours > 0 && cloud.len() > self.outlier_neighbours {
            cloud = pointcloud::filter::remove_statistical_outliers(
                &cloud,
                self.outlier_neighbours,
                self.outlier_std_ratio,
            )?
            .0;
        }
        if let Some(g) = self.gsd {
            cloud = pointcloud::thin::thin_to_grid(&cloud, g, &["agreeing_views"], &["depth_spread"])?.0;
        }
        if let Some(n) = self.points {
            cloud = pointcloud::filter::subsample(&cloud, n, self.seed)?.0;
        }
        Ok(cloud)
    }
}

/// The careful export's spread and consistency filters from their settings (`export pointcloud`, `dsm` and `ortho`
/// share them): 0 turns a filter off; errors name the flag.
pub fn careful_filters(
    max_spread_cells: f64,
    check_views: usize,
    min_agree: usize,
    agree_tolerance: f64,
) -> Result<(Option<f64>, Option<Consistency>), ProductError> {
    if !(max_spread_cells.is_finite() && max_spread_cells >= 0.0) {
        return Err(ProductError::option("--max-spread-cells", format!("must be >= 0, got {max_spread_cells}")));
    }
    if !(agree_tolerance.is_finite() && agree_tolerance > 0.0) {
        return Err(ProductError::option("--agree-tolerance", format!("must be > 0, got {agree_tolerance}")));
    }
    if !(check_views == 0 || (1..=check_views).contains(&min_agree)) {
        return Err(ProductError::option(
            "--min-agree",
            format!("must be between 1 and --check-views ({check_views}), got {min_agree}"),
        ));
    }
    Ok((
        (max_spread_cells > 0.0).then_some(max_spread_cells),
        (check_views > 0).then_some(Consistency { views: check_views, min_agree, tolerance: agree_tolerance }),
    ))
}

/// Writes `cloud` as PLY or LAS (by extension), carrying the dataset's `crs`: LAS as its OGC WKT record
/// (`LASF_Projection`/2112), PLY as `comment crs EPSG:n` and `comment crs_wkt WKT` lines. An empty cloud is refused:
/// a product with no point is a failure to report, not a file.
pub fn write_cloud(cloud: &PointCloud, out: &Path, crs: Option<&Crs>) -> Result<(), ProductError> {
    if cloud.is_empty() {
        return Err(ProductError::option(
            "cloud",
            format!("{}: no point survived the filters, nothing written", out.display()),
        ));
    }
    match out.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("ply") => {
            let comments =
                crs.map(|c| vec![format!("crs {}", c.key()), format!("crs_wkt {}", c.wkt)]).unwrap_or_default();
            pointcloud::write_ply(out, cloud, &PlyOptions { comments, ..Default::default() })?
        }
        Some("las") => {
            pointcloud::write_las(out, cloud, &LasOptions { wkt: crs.map(|c| c.wkt.clone()), ..Default::default() })?
        }
        _ => {
            return Err(ProductError::option("--out", format!("{}: the file must end in .ply or .las", out.display())))
        }
    }
    Ok(())
}

/// One line per filter: what it removed.
pub fn summary(s: &ExportStats, min_accumulation: f32, written: usize) -> String {
    format!(
        "{} rays rendered: {} below accumulation {min_accumulation}, {} outside the scene box, {} with spread weights, \
         {} inconsistent across views ({} check rays); {} points kept, {} written after outlier removal and thinning",
        s.rays,
        s.below_accumulation,
        s.outside_box,
        s.spread,
        s.inconsistent,
        s.check_rays,
        s.kept,
        written
    ) + &refine_summary(s)
}

/// A note when the refinement dropped most of the consistent points: the images carry little texture (uniform
/// materials), and the user should know the flags that keep them.
pub fn unsupported_note(s: &ExportStats) -> Option<String> {
    let points = s.refine.as_ref().map_or(0, |r| r.points);
    (points > 0 && 2 * s.unsupported > points).then(|| {
        format!(
            "note: {} of {points} consistent points ({:.0} %) had no photometric support and were dropped: the \
             training images carry little texture there (uniform surfaces), or the surface lies beyond \
             --refine-range; --keep-unsupported keeps them where the field put them, --no-refine skips the refinement",
            s.unsupported,
            100.0 * s.unsupported as f64 / points as f64
        )
    })
}

/// The refinement's line of the summary (empty when it was off).
fn refine_summary(s: &ExportStats) -> String {
    match &s.refine {
        None => String::new(),
        Some(r) => match &r.skipped {
            Some(why) => format!("; photometric refinement skipped: {why}"),
            None => format!(
                "; photometric refinement moved {} of {} points (median |shift| {:.3} in world units), kept {} where \
                 the field put them (weak correlation), {} without photometric support {}",
                r.moved,
                r.points,
                r.median_shift,
                r.kept,
                r.points - r.moved - r.kept,
                if s.unsupported > 0 { "dropped" } else { "kept" }
            ),
        },
    }
}
