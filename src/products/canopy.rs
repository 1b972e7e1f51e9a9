//! The terrain and canopy products as files, on the DSM's grid and in its CRS: `export dtm` (SMRF ground filtering
//! of a DSM GeoTIFF, [`make_dtm`]), `export chm` (DSM - DTM, [`make_chm`]) and `export trees` (tops, crowns and their
//! attributes from a CHM, [`make_trees`]). `process` calls the same functions after its survey stage. Rasters are
//! Cloud-Optimized GeoTIFFs (nodata -9999) with hillshade and colour previews; every file is written under a
//! temporary name and renamed, so a failure leaves no partial product.
//!
//! A DSM written by `export dsm` has `<stem>_quality.tif` beside it: only its measured and interpolated cells are
//! ground candidates (a field-only height is not a measurement; see `nerf::survey::quality`), unless
//! `use_field_heights` says otherwise. The CHM carries the DSM's quality raster, and tree tops and crowns are
//! sought only on its measured and interpolated cells.

use std::path::{Path, PathBuf};

use super::terrain::{canopy_height, smrf, HeightGrid, SmrfParams};
use super::trees::{
    describe_trees, find_tops, grow_crowns, median_3x3, table, CrownParams, TopParams, Tree, TreeBands,
};
use super::ProductError;
use crate::nerf::survey::quality;
use crate::nerf::survey_products::{dsm_previews, sibling, write_quality, write_views, NODATA, PREVIEW_MAX};
use crate::output::image::band_from_description;
use crate::output::raster::geotiff_read::{read_geotiff, GeoRaster, RasterGrid};
use crate::output::raster::{CogOptions, CogWriter, GeoReference, GeoTiffOptions};
use crate::output::SpectralImage;

/// Largest raster these products read (cells), as `export dsm`'s default `--max-cells`.
pub const MAX_CELLS: usize = 200_000_000;

/// A single-band height raster read from a GeoTIFF.
pub struct HeightRaster {
    pub path: PathBuf,
    pub grid: RasterGrid,
    pub heights: HeightGrid,
}

impl HeightRaster {
    pub fn georef(&self) -> GeoReference {
        GeoReference { origin: self.grid.origin, pixel_size: self.grid.pixel_size, epsg: self.grid.epsg }
    }
}

/// Reads band 1 of the GeoTIFF at `path` as heights (nodata as NaN); square cells and at most [`MAX_CELLS`].
pub fn read_heights(path: &Path) -> Result<HeightRaster, ProductError> {
    let grid = crate::output::raster::geotiff_read::read_grid(path)?;
    check_grid(path, &grid)?;
    let r = read_geotiff(path)?;
    let n = grid.width * grid.height;
    let z: Vec<f32> = r.data[..n].iter().map(|&v| if r.is_nodata(v) { f32::NAN } else { v }).collect();
    let heights = HeightGrid { width: grid.width, height: grid.height, gsd: grid.pixel_size[0], z };
    Ok(HeightRaster { path: path.to_path_buf(), grid: r.grid, heights })
}

fn check_grid(path: &Path, g: &RasterGrid) -> Result<(), ProductError> {
    if (g.pixel_size[0] - g.pixel_size[1]).abs() > 1e-9 * g.pixel_size[0] {
        return Err(ProductError::input(
            path,
            format!("cells of {} x {} are not square", g.pixel_size[0], g.pixel_size[1]),
        ));
    }
    if g.width * g.height > MAX_CELLS {
        return Err(ProductError::input(path, format!("{} x {} cells, more than {MAX_CELLS}", g.width, g.height)));
    }
    Ok(())
}

/// Whether two rasters share one grid (origin and cell size to a thousandth of a cell, and size).
pub fn same_grid(a: &RasterGrid, b: &RasterGrid) -> bool {
    let tol = 1e-3 * a.pixel_size[0];
    a.width == b.width
        && a.height == b.height
        && (a.origin[0] - b.origin[0]).abs() <= tol
        && (a.origin[1] - b.origin[1]).abs() <= tol
        && (a.pixel_size[0] - b.pixel_size[0]).abs() <= 1e-9 * a.pixel_size[0]
}

fn require_same_grid(base: &HeightRaster, path: &Path, g: &RasterGrid) -> Result<(), ProductError> {
    if same_grid(&base.grid, g) {
        return Ok(());
    }
    Err(ProductError::input(
        path,
        format!(
            "its grid ({} x {} cells of {} from {:?}) is not {}'s ({} x {} of {} from {:?}); make both on one grid \
             (export dsm/ortho --align-to)",
            g.width,
            g.height,
            g.pixel_size[0],
            g.origin,
            base.path.display(),
            base.grid.width,
            base.grid.height,
            base.grid.pixel_size[0],
            base.grid.origin
        ),
    ))
}

/// Writes `hg` as a COG at `path` (nodata [`NODATA`]) with `<stem>_hillshade.png` and `<stem>_height.png`.
pub fn write_height_cog(
    path: &Path,
    hg: &HeightGrid,
    georef: GeoReference,
    name: &str,
    metadata: Vec<(String, String)>,
) -> Result<Vec<PathBuf>, ProductError> {
    let opts = CogOptions {
        geotiff: GeoTiffOptions { nodata: Some(NODATA), georef: Some(georef), bigtiff: None, metadata },
        preview_max: PREVIEW_MAX,
    };
    let band = vec![crate::output::image::band(name, None, None)];
    let mut wr = CogWriter::create(path, hg.width, hg.height, band, &opts)?;
    let mut row = vec![0.0f32; hg.width];
    for r in 0..hg.height {
        for (o, &v) in row.iter_mut().zip(&hg.z[r * hg.width..(r + 1) * hg.width]) {
            *o = if v.is_finite() { v } else { NODATA as f32 };
        }
        wr.push_rows(&row)?;
    }
    let mut files = vec![path.to_path_buf()];
    if let Some(pv) = wr.finish()? {
        files.extend(dsm_previews(path, &pv, hg.gsd)?);
    }
    Ok(files)
}

/// The raster `<base stem><suffix>` beside `base` (its quality or view counts), checked to share `base`'s grid; None
/// when there is none.
fn sidecar(base: &HeightRaster, suffix: &str) -> Result<Option<GeoRaster>, ProductError> {
    let path = sibling(&base.path, suffix);
    if !path.is_file() {
        return Ok(None);
    }
    let r = read_geotiff(&path)?;
    require_same_grid(base, &path, &r.grid)?;
    Ok(Some(r))
}

/// What [`make_dtm`] did.
#[derive(Debug, Clone)]
pub struct DtmSummary {
    pub files: Vec<PathBuf>,
    /// DSM cells with a height.
    pub dsm_cells: usize,
    /// Cells SMRF took as candidates (measured or interpolated, or all with `use_field_heights`).
    pub candidates: usize,
    /// Cells judged ground.
    pub ground: usize,
    /// DTM cells with a height.
    pub dtm_cells: usize,
    /// DSM cells per SMRF cell along each axis.
    pub factor: usize,
}

impl DtmSummary {
    pub fn line(&self) -> String {
        let pct = |a: usize, b: usize| if b == 0 { 0.0 } else { 100.0 * a as f64 / b as f64 };
        format!(
            "DTM: {} of {} DSM cells were candidates, {} ({:.1}%) ground; {} cells of terrain ({:.1}% interpolated \
             under objects or gaps); SMRF cells of {} DSM cells",
            self.candidates,
            self.dsm_cells,
            self.ground,
            pct(self.ground, self.candidates),
            self.dtm_cells,
            pct(self.dtm_cells - self.ground.min(self.dtm_cells), self.dtm_cells),
            self.factor
        )
    }
}

/// The DTM of the DSM at `dsm` by SMRF with `p`, written to `out` (COG), with `<out stem>_quality.tif` (1: a ground
/// cell of the DSM, 2: interpolated beneath an object or across a gap) and previews.
pub fn make_dtm(dsm: &Path, out: &Path, p: &SmrfParams, use_field_heights: bool) -> Result<DtmSummary, ProductError> {
    p.validate().map_err(|(k, why)| ProductError::option(&format!("smrf {k}"), why))?;
    let d = read_heights(dsm)?;
    let n = d.heights.cells();
    let dsm_cells = d.heights.valid();
    if dsm_cells == 0 {
        return Err(ProductError::input(dsm, "no cell has a height (every cell is nodata)"));
    }
    let q_path = sibling(dsm, "_quality.tif");
    let usable: Vec<bool> = match sidecar(&d, "_quality.tif")?.filter(|_| !use_field_heights) {
        Some(q) => q.data[..n].iter().map(|&c| matches!(c as u8, quality::MEASURED | quality::INTERPOLATED)).collect(),
        None => vec![true; n],
    };
    let candidates = (0..n).filter(|&i| usable[i] && d.heights.z[i].is_finite()).count();
    if candidates == 0 {
        return Err(ProductError::input(
            dsm,
            format!(
                "no cell is measured or interpolated ({} says every height is the field's alone or nodata: a \
                 flight over water or uniform surfaces, or a DSM made without the photometric refinement); \
                 --use-field-heights filters the field's heights",
                q_path.display()
            ),
        ));
    }
    let s = smrf(&d.heights, &usable, p);
    let ground = s.ground_cells();
    if ground == 0 {
        return Err(ProductError::input(dsm, "SMRF found no ground cell: nothing to make a terrain model from"));
    }
    let dtm_cells = s.dtm.valid();
    let meta = vec![
        ("msnerf_product".into(), "DTM: SMRF ground filter of a DSM".into()),
        ("msnerf_dsm".into(), dsm.display().to_string()),
        (
            "smrf".into(),
            format!(
                "cell={} slope={} window={} threshold={} scalar={}",
                p.cell, p.slope, p.window, p.threshold, p.scalar
            ),
        ),
    ];
    let mut files = write_height_cog(out, &s.dtm, d.georef(), "terrain height", meta)?;
    let codes: Vec<u8> = (0..n)
        .map(|i| match (s.ground[i], s.dtm.z[i].is_finite()) {
            (true, _) => quality::MEASURED,
            (false, true) => quality::INTERPOLATED,
            _ => quality::NODATA,
        })
        .collect();
    let (w, h) = (d.heights.width, d.heights.height);
    let what = "DTM quality: 1 ground cell of the DSM, 2 interpolated beneath objects or gaps, 0 nodata";
    files.extend(write_quality(out, &codes, w, h, &d.georef(), what, &dsm.display().to_string())?);
    Ok(DtmSummary { files, dsm_cells, candidates, ground, dtm_cells, factor: s.factor })
}

/// What [`make_chm`] did.
#[derive(Debug, Clone)]
pub struct ChmSummary {
    pub files: Vec<PathBuf>,
    pub cells: usize,
    /// Cells at least 2 m above the terrain.
    pub above_2m: usize,
    pub max: f64,
}

impl ChmSummary {
    pub fn line(&self) -> String {
        let pct = if self.cells == 0 { 0.0 } else { 100.0 * self.above_2m as f64 / self.cells as f64 };
        format!("CHM: {} cells, {pct:.1}% at least 2 above the terrain, highest {:.2}", self.cells, self.max)
    }
}

/// DSM - DTM ([`canopy_height`]) of the rasters at `dsm` and `dtm` (one grid), written to `out`.
pub fn make_chm(dsm: &Path, dtm: &Path, out: &Path) -> Result<ChmSummary, ProductError> {
    let s = read_heights(dsm)?;
    let t = read_heights(dtm)?;
    require_same_grid(&s, dtm, &t.grid)?;
    let chm = canopy_height(&s.heights, &t.heights);
    let cells = chm.valid();
    if cells == 0 {
        return Err(ProductError::input(dtm, format!("no cell has a height in both it and {}", dsm.display())));
    }
    let above_2m = chm.z.iter().filter(|&&v| v >= 2.0).count();
    let max = chm.z.iter().copied().filter(|v| v.is_finite()).fold(0.0f32, f32::max) as f64;
    let meta = vec![
        ("msnerf_product".into(), "CHM: DSM - DTM, at least 0".into()),
        ("msnerf_dsm".into(), dsm.display().to_string()),
        ("msnerf_dtm".into(), dtm.display().to_string()),
    ];
    let mut files = write_height_cog(out, &chm, s.georef(), "height above terrain", meta)?;
    // The DSM's quality, carried cell for cell: `export trees` does not take a field-only height for a crown.
    if let Some(q) = sidecar(&s, "_quality.tif")? {
        let codes: Vec<u8> =
            chm.z.iter().zip(&q.data).map(|(z, &c)| if z.is_finite() { c as u8 } else { quality::NODATA }).collect();
        let what = "CHM quality (the DSM's): 1 measured, 2 interpolated, 3 field only, 0 nodata";
        let (w, h) = (chm.width, chm.height);
        files.extend(write_quality(out, &codes, w, h, &s.georef(), what, &dsm.display().to_string())?);
    }
    // And its view counts: `export trees` weighs a top seen by few images.
    if let Some(v) = sidecar(&s, "_views.tif")? {
        let counts: Vec<f32> =
            chm.z.iter().zip(&v.data).map(|(z, &n)| if z.is_finite() { n } else { f32::NAN }).collect();
        let size = (chm.width, chm.height);
        files.push(write_views(out, counts, size, &s.georef(), &dsm.display().to_string())?);
    }
    Ok(ChmSummary { files, cells, above_2m, max })
}

/// What [`make_trees`] found.
#[derive(Debug, Clone)]
pub struct TreesSummary {
    pub files: Vec<PathBuf>,
    /// The trees written.
    pub trees: Vec<Tree>,
    /// Tops whose crown is not vegetation (NDVI below [`super::trees::attributes::MIN_NDVI`]): roofs, cars.
    pub not_vegetation: usize,
    /// Tops whose crown is too small for a tree of their height ([`CrownParams::min_area_fraction`]), too little of
    /// it measured ([`CrownParams::min_support`]), or seen by too few images ([`TopParams::min_views`]).
    pub too_small: usize,
    pub notes: Vec<String>,
}

impl TreesSummary {
    pub fn line(&self) -> String {
        let hs: Vec<f64> = self.trees.iter().map(|t| t.height).collect();
        let (lo, hi) = hs.iter().fold((f64::MAX, f64::MIN), |(a, b), &h| (a.min(h), b.max(h)));
        let range = if hs.is_empty() { String::new() } else { format!(", {lo:.1} to {hi:.1} high") };
        format!(
            "trees: {} found{range}; tops set apart: {} not vegetation (NDVI below {}), {} with too small, too little \
             measured or too seldom seen a crown",
            self.trees.len(),
            self.not_vegetation,
            super::trees::attributes::MIN_NDVI,
            self.too_small
        )
    }
}

/// Trees of the CHM at `chm`: tops, crowns, attributes (`dtm` for the ground height, `ortho` for band means and
/// indices; both on the CHM's grid), written to `out` (GeoJSON), `<stem>.csv` and `<stem>_crowns.tif` (the crown id
/// of every cell, nodata 0).
pub fn make_trees(
    chm: &Path,
    dtm: Option<&Path>,
    ortho: Option<&Path>,
    out: &Path,
    tops: &TopParams,
    crowns: &CrownParams,
) -> Result<TreesSummary, ProductError> {
    let c = read_heights(chm)?;
    if c.heights.valid() == 0 {
        return Err(ProductError::input(chm, "no cell has a height (every cell is nodata)"));
    }
    let t = match dtm {
        Some(p) => {
            let t = read_heights(p)?;
            require_same_grid(&c, p, &t.grid)?;
            Some(t)
        }
        None => None,
    };
    let mut notes = Vec::new();
    let bands = match ortho {
        Some(p) => {
            let o = read_geotiff(p)?;
            require_same_grid(&c, p, &o.grid)?;
            let bands: Vec<_> = (0..o.grid.bands)
                .map(|b| match o.grid.descriptions.get(b).filter(|s| !s.is_empty()) {
                    Some(d) => band_from_description(d),
                    None => crate::output::image::band(&format!("band{}", b + 1), None, None),
                })
                .collect();
            let mut data = o.data.clone();
            data.iter_mut().filter(|v| o.is_nodata(**v)).for_each(|v| *v = f32::NAN);
            Some(TreeBands { bands, data })
        }
        None => {
            notes.push("no orthomosaic: no band means, and roofs cannot be told from crowns".into());
            None
        }
    };
    // Which cells the DSM measured or interpolated (the CHM's quality, copied from the DSM's): a crown needs some.
    let supported: Option<Vec<bool>> = sidecar(&c, "_quality.tif")?
        .map(|q| q.data.iter().map(|&code| matches!(code as u8, quality::MEASURED | quality::INTERPOLATED)).collect());
    // How many training images saw each cell (the CHM's copy of the DSM's view counts).
    let views: Option<Vec<f32>> = sidecar(&c, "_views.tif")?.map(|v| v.data);
    // Tops, crowns and heights on the smoothed surface (a top's own cell may be a pit between leaves).
    let smooth = median_3x3(&c.heights);
    let top_cells = find_tops(&smooth, tops);
    let labels = grow_crowns(&smooth, &top_cells, crowns);
    let dtm_heights = t.as_ref().map(|t| &t.heights);
    let (tl, sup) = ((&top_cells[..], &labels[..]), supported.as_deref());
    let mut all = describe_trees(&smooth, dtm_heights, c.grid.origin, tl, bands.as_ref(), sup);
    if let Some(v) = &views {
        for (tr, &cell) in all.iter_mut().zip(&top_cells) {
            tr.views = Some(v[cell] as f64).filter(|n| n.is_finite());
        }
    }
    if bands.is_some() && all.iter().all(|t| t.ndvi.is_none()) && !all.is_empty() {
        notes.push("the orthomosaic has no red and NIR bands: NDVI unknown, roofs cannot be told from crowns".into());
    }
    // Keep the vegetation whose crown is as wide as a tree's; renumber so the table's ids and the crown raster's
    // agree.
    let big_enough = |t: &Tree| {
        let r = tops.radius(t.height);
        t.crown_area >= crowns.min_area_fraction * std::f64::consts::PI * r * r
            && t.support.is_none_or(|s| s >= crowns.min_support)
            && t.views.is_none_or(|n| n >= tops.min_views as f64)
    };
    let mut renumber = vec![0u32; all.len() + 1];
    let mut trees = Vec::new();
    let too_small = all.iter().filter(|t| !big_enough(t)).count();
    for tr in all.iter().filter(|t| big_enough(t) && t.is_vegetation()) {
        let mut tr = tr.clone();
        renumber[tr.id as usize] = trees.len() as u32 + 1;
        tr.id = trees.len() as u32 + 1;
        trees.push(tr);
    }
    let not_vegetation = all.len() - trees.len() - too_small;
    let crown_ids: Vec<f32> = labels.iter().map(|&l| renumber[l as usize] as f32).collect();
    let band_list = bands.as_ref().map(|b| b.bands.clone()).unwrap_or_default();
    table::write_geojson(out, &trees, &band_list, c.grid.epsg)?;
    let csv = out.with_extension("csv");
    table::write_csv(&csv, &trees, &band_list)?;
    let crowns_path = sibling(out, "_crowns.tif");
    let img = SpectralImage::single(
        c.grid.width,
        c.grid.height,
        crate::output::image::band("crown id", None, None),
        crown_ids,
    )?;
    let opts = GeoTiffOptions {
        nodata: Some(0.0),
        georef: Some(c.georef()),
        bigtiff: None,
        metadata: vec![("msnerf_product".into(), "tree crowns: the id of each crown in the tree table, 0 none".into())],
    };
    crate::output::raster::write_geotiff(&crowns_path, &img, &opts)?;
    Ok(TreesSummary { files: vec![out.to_path_buf(), csv, crowns_path], trees, not_vegetation, too_small, notes })
}
