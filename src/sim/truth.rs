//! Ground truth for the survey products of issue 21, written beside every simulated dataset in `truth/`:
//! - `dsm.tif`: per grid cell, the height (world z, `world_offset` included) of the first surface straight down at
//!   the cell centre: float32, nodata NaN where the vertical ray meets no surface (outside the ground disc);
//! - `ortho.tif`: the same cells' band reflectance seen from straight above (the surface's band-integrated
//!   Lambertian reflectance times its texture factor, as the images show it without light or sensor effects):
//!   a true orthophoto, no leaning buildings;
//! - `classes.tif`: what the vertical ray hit: 1 ground, 2 roof (a flat top: an object hit with a normal within 8
//!   degrees of vertical), 3 other object (walls seen edge-on, crowns, domes), NaN nothing; the band is named
//!   `classes 1=ground 2=roof 3=object`, which `msnerf compare-raster --classes` reads;
//! - `materials.tif`: the material the vertical ray hit, as 1 + its index in the scene's material list (sorted by
//!   name), the band named `classes 1=asphalt 2=bark ...` the same way, so `compare-raster --classes
//!   truth/materials.tif` reports a DSM's or an orthomosaic's error per material (textured and uniform surfaces
//!   apart; docs/geometry.md).
//!
//! - `dtm.tif`: the bare earth under every cell that has a surface (the ground plane, z = 0 plus the offset: under
//!   buildings and crowns too);
//! - `chm.tif`: the height of the first surface above the bare earth (`dsm - dtm`: 0 on open ground, a crown's or a
//!   roof's height above it);
//! - `trees.geojson` and `trees.csv`: every tree whose trunk stands inside the grid, as `msnerf export trees` writes
//!   its table: the trunk's position, the height of the crown's top above the ground (trunk height + the crown's
//!   vertical diameter), the crown's area (its ellipse, pi rx ry) and equivalent diameter.
//!
//! All are north-up GeoTIFFs on one grid, in the scene's `crs` when it has one.
//!
//! The grid covers what the cameras saw (the bounding box of the ground-truth surface points, snapped outward to
//! whole cells) at the cameras' median ground footprint (height above the ground / focal length), so a DSM exported
//! at the same GSD can be compared cell by cell.

use std::path::Path;

use super::geometry::HitKind;
use super::render::Prepared;
use super::SimError;
use crate::output::raster::{write_geotiff, GeoReference, GeoTiffOptions};
use crate::output::SpectralImage;

/// A north-up grid in the scene's local frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthGrid {
    /// Local x, y of the top-left corner of the top-left cell.
    pub origin: [f64; 2],
    pub gsd: f64,
    pub width: usize,
    pub height: usize,
}

impl TruthGrid {
    /// Local x, y of the centre of cell (row, col).
    pub fn centre(&self, row: usize, col: usize) -> [f64; 2] {
        [self.origin[0] + (col as f64 + 0.5) * self.gsd, self.origin[1] - (row as f64 + 0.5) * self.gsd]
    }
}

/// The grid over `points` (local surface points) at `gsd`; None without points.
pub fn grid_over(points: &[[f64; 3]], gsd: f64) -> Option<TruthGrid> {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in points {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if points.is_empty() || gsd.is_nan() || gsd <= 0.0 {
        return None;
    }
    let x0 = (lo[0] / gsd).floor() * gsd;
    let y1 = (hi[1] / gsd).ceil() * gsd;
    let width = (((hi[0] - x0) / gsd).ceil() as usize).max(1);
    let height = (((y1 - lo[1]) / gsd).ceil() as usize).max(1);
    Some(TruthGrid { origin: [x0, y1], gsd, width, height })
}

/// The cameras' median ground footprint: height above the ground (z = 0) over the focal length in pixels.
pub fn median_footprint(prep: &Prepared) -> f64 {
    let f = 0.5 * (prep.camera.fx + prep.camera.fy);
    let v: Vec<f64> = prep.poses.iter().map(|m| m[2][3].max(0.0) / f).collect();
    crate::util::stats::median(&v)
}

/// The class band's name: codes of [`trace_grid`]'s classes.
pub const CLASS_BAND: &str = "classes 1=ground 2=roof 3=object";

/// The material band's name: `classes 1=<first material> 2=<second> ...` (codes of [`TracedGrid::material`]);
/// whitespace and `=` in a material's name become `_`, so the name still parses as one code=name pair.
pub fn material_band(prep: &Prepared) -> String {
    let safe = |n: &str| n.replace(|c: char| c.is_whitespace() || c == '=', "_");
    let names: Vec<String> =
        prep.materials.iter().enumerate().map(|(i, m)| format!("{}={}", i + 1, safe(&m.name))).collect();
    format!("classes {}", names.join(" "))
}

/// What [`trace_grid`] finds in every cell (row-major; NaN: no surface).
pub struct TracedGrid {
    /// Local z of the first surface straight down.
    pub dsm: Vec<f32>,
    /// Band-planar reflectance times texture.
    pub refl: Vec<f32>,
    /// 1 ground, 2 roof, 3 other object (see the module doc).
    pub class: Vec<f32>,
    /// 1 + the material index.
    pub material: Vec<f32>,
}

/// Heights, band-planar reflectance, class and material (see the module doc) of every cell, tracing straight down.
pub fn trace_grid(prep: &Prepared, g: &TruthGrid) -> TracedGrid {
    let nb = prep.bands.len();
    let n = g.width * g.height;
    let top = prep.world.extent * 0.5;
    let mut dsm = vec![f32::NAN; n];
    let mut refl = vec![f32::NAN; n * nb];
    let mut class = vec![f32::NAN; n];
    let mut material = vec![f32::NAN; n];
    for row in 0..g.height {
        for col in 0..g.width {
            let [x, y] = g.centre(row, col);
            let o = [x, y, top];
            if !prep.world.contains(o) {
                continue;
            }
            let hit = prep.world.trace(o, [0.0, 0.0, -1.0]);
            if hit.kind == HitKind::Horizon {
                continue;
            }
            let q = [x, y, top - hit.t];
            let c = row * g.width + col;
            dsm[c] = q[2] as f32;
            class[c] = match hit.kind {
                HitKind::Ground => 1.0,
                _ if hit.normal[2] > 0.99 => 2.0,
                _ => 3.0,
            };
            material[c] = (hit.material + 1) as f32;
            let m = &prep.materials[hit.material];
            let tex = m.texture.map_or(1.0, |t| t.factor(prep.seed, hit.material, q));
            for (b, r) in m.refl.iter().enumerate() {
                refl[b * n + c] = (r * tex) as f32;
            }
        }
    }
    TracedGrid { dsm, refl, class, material }
}

/// Writes `truth/dsm.tif`, `ortho.tif`, `classes.tif`, `materials.tif`, `dtm.tif`, `chm.tif` and the tree table
/// under `root` for the surface points the cameras saw.
pub fn write_truth(prep: &Prepared, root: &Path, points: &[[f64; 3]]) -> Result<Option<TruthGrid>, SimError> {
    let Some(g) = grid_over(points, median_footprint(prep)) else { return Ok(None) };
    let TracedGrid { mut dsm, refl, class, material } = trace_grid(prep, &g);
    let o = prep.world_offset;
    dsm.iter_mut().for_each(|z| *z += o[2] as f32);
    let dir = root.join("truth");
    std::fs::create_dir_all(&dir).map_err(SimError::io(&dir))?;
    let georef = GeoReference::in_crs([g.origin[0] + o[0], g.origin[1] + o[1]], [g.gsd, g.gsd], prep.crs.as_ref())?;
    let opts = |what: &str| GeoTiffOptions {
        nodata: Some(f64::NAN),
        georef: Some(georef),
        metadata: vec![("msnerf_truth".into(), what.into()), ("scene".into(), prep.name.clone())],
        ..Default::default()
    };
    let height_band = vec![crate::output::image::band("height", None, None)];
    let img = SpectralImage::from_planar(g.width, g.height, height_band, dsm.clone())?;
    write_geotiff(&dir.join("dsm.tif"), &img, &opts("first-surface height (world z, metres), straight down"))?;
    let bands: Vec<crate::data::Band> =
        prep.bands.iter().map(|b| crate::output::image::band(&b.name, Some(b.center_nm), Some(b.fwhm_nm))).collect();
    let img = SpectralImage::from_planar(g.width, g.height, bands, refl)?;
    write_geotiff(&dir.join("ortho.tif"), &img, &opts("true orthophoto: band reflectance x texture, straight down"))?;
    let img =
        SpectralImage::from_planar(g.width, g.height, vec![crate::output::image::band(CLASS_BAND, None, None)], class)?;
    write_geotiff(&dir.join("classes.tif"), &img, &opts("what the vertical ray hit"))?;
    let band = vec![crate::output::image::band(&material_band(prep), None, None)];
    let img = SpectralImage::from_planar(g.width, g.height, band, material)?;
    write_geotiff(&dir.join("materials.tif"), &img, &opts("the material the vertical ray hit"))?;
    let ground = o[2] as f32;
    let dtm: Vec<f32> = dsm.iter().map(|z| if z.is_finite() { ground } else { f32::NAN }).collect();
    let chm: Vec<f32> = dsm.iter().map(|z| z - ground).collect();
    let img = SpectralImage::single(g.width, g.height, crate::output::image::band("terrain height", None, None), dtm)?;
    write_geotiff(&dir.join("dtm.tif"), &img, &opts("bare earth (world z, metres) under every surface"))?;
    let band = crate::output::image::band("height above terrain", None, None);
    let img = SpectralImage::single(g.width, g.height, band, chm)?;
    write_geotiff(&dir.join("chm.tif"), &img, &opts("first surface above the bare earth (metres)"))?;
    let trees = truth_trees(prep, &g);
    let epsg = georef.epsg;
    crate::products::trees::table::write_geojson(&dir.join("trees.geojson"), &trees, &[], epsg)?;
    crate::products::trees::table::write_csv(&dir.join("trees.csv"), &trees, &[])?;
    Ok(Some(g))
}

/// The scene's trees whose trunk stands inside grid `g`, in world coordinates (see the module doc).
pub fn truth_trees(prep: &Prepared, g: &TruthGrid) -> Vec<crate::products::trees::Tree> {
    let o = prep.world_offset;
    let (x1, y0) = (g.origin[0] + g.width as f64 * g.gsd, g.origin[1] - g.height as f64 * g.gsd);
    prep.trees
        .iter()
        .filter(|t| (g.origin[0]..x1).contains(&t.position[0]) && (y0..g.origin[1]).contains(&t.position[1]))
        .enumerate()
        .map(|(i, t)| {
            let area = std::f64::consts::PI * t.crown[0] * t.crown[1];
            crate::products::trees::Tree {
                id: i as u32 + 1,
                x: t.position[0] + o[0],
                y: t.position[1] + o[1],
                height: t.trunk_height + 2.0 * t.crown[2],
                ground_z: o[2],
                crown_area: area,
                crown_diameter: 2.0 * (t.crown[0] * t.crown[1]).sqrt(),
                band_means: Vec::new(),
                ndvi: None,
                ndre: None,
                support: None,
                views: None,
            }
        })
        .collect()
}
