//! Writes the survey products of [`super::survey`] as files: the DSM (one float32 band, world z), the true
//! orthomosaic (B float32 bands with names and wavelengths) and vegetation indices, each a Cloud-Optimized GeoTIFF
//! on the same grid (`output::raster::cog`, streamed block by block), in the dataset's `crs` when it has one, nodata
//! -9999 (OpenDroneMap's and PDAL's DSM convention); and PNG previews from the coarsest overview that fits
//! [`PREVIEW_MAX`]: `<stem>_hillshade.png` and `<stem>_height.png` for the DSM, `<stem>_rgb.png`, `<stem>_cir.png`
//! and `<stem>_ndvi.png` for the ortho (where its bands allow), `<stem>_<index>.png` for each index.
//!
//! Every path is checked before rendering starts (extension, existing folder, bands for each index); a failure
//! while rendering leaves no product behind (the writers' temporary files are removed).

use std::path::{Path, PathBuf};

use super::run::LoadedRun;
use super::survey::{
    median_camera_height, quality, render_survey, DsmFill, RowBlock, SurveyError, SurveyGrid, SurveyOptions,
    SurveyStats, FILL_MAX_CELLS,
};
use crate::output::image::{band, band_description};
use crate::output::raster::cog::{CogOptions, CogPreview, CogWriter};
use crate::output::raster::hillshade::{hillshade, Sun};
use crate::output::raster::indices::{bands_for_index, VegetationIndex, DEFAULT_TOLERANCE_NM};
use crate::output::raster::preview::{self, Rgb8, Stretch};
use crate::output::raster::{Colormap, GeoReference, GeoTiffOptions};
use crate::output::SpectralImage;

/// Nodata of every survey product.
pub const NODATA: f64 = -9999.0;
/// Largest side of the preview PNGs (the coarsest COG level that fits).
pub const PREVIEW_MAX: usize = 2048;

/// Which products to write.
#[derive(Debug, Clone, Default)]
pub struct SurveyOutputs {
    pub dsm: Option<PathBuf>,
    pub ortho: Option<PathBuf>,
    /// Index GeoTIFFs written beside the ortho as `<stem>_<index>.tif` (needs `ortho`).
    pub indices: Vec<VegetationIndex>,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct SurveyReport {
    pub grid: SurveyGrid,
    pub stats: SurveyStats,
    pub files: Vec<PathBuf>,
    /// Previews that the bands did not allow, with the reason.
    pub notes: Vec<String>,
}

/// `dir/<stem><suffix>` of `path`.
pub fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!("{stem}{suffix}"))
}

fn check_path(path: &Path, what: &str) -> Result<(), SurveyError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("tif" | "tiff")) {
        return Err(SurveyError::Invalid {
            what: what.into(),
            reason: format!("{}: the file must end in .tif", path.display()),
        });
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        return Err(SurveyError::Invalid {
            what: what.into(),
            reason: format!("{}: the folder {} does not exist", path.display(), dir.display()),
        });
    }
    Ok(())
}

/// What the products describe, wherever their rendering comes from (one run, or merged blocks).
#[derive(Debug, Clone)]
pub struct SurveySource {
    pub bands: Vec<crate::data::Band>,
    pub crs: Option<crate::geo::Crs>,
    /// Written into the products' metadata (`msnerf_run`): the run folder, or the BLOCKS folder.
    pub label: String,
    /// World z the vertical rays start from.
    pub top: f64,
    /// The training cameras, for the DSM's view-count raster (none: no such raster).
    pub views: Vec<ViewCamera>,
}

/// A training camera: intrinsics, centre and camera-to-world rotation (rows), world frame.
#[derive(Debug, Clone)]
pub struct ViewCamera {
    pub camera: crate::data::Camera,
    pub origin: [f64; 3],
    pub rot: [[f64; 3]; 3],
}

/// The training views of `ds` as [`ViewCamera`]s.
pub fn training_views(ds: &crate::data::Dataset) -> Vec<ViewCamera> {
    ds.split_indices(crate::data::Split::Train)
        .iter()
        .map(|&f| {
            let m = &ds.frames[f].c2w;
            ViewCamera {
                camera: ds.frames[f].camera,
                origin: [m[0][3], m[1][3], m[2][3]],
                rot: [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]),
            }
        })
        .collect()
}

/// Per cell with a height, the number of `views` whose image holds the cell's surface point (its centre at that
/// height; occlusion is not tested): how many training images could have seen it. NaN where there is no height.
pub fn view_counts(z: &[f32], grid: &SurveyGrid, views: &[ViewCamera]) -> Vec<f32> {
    z.iter()
        .enumerate()
        .map(|(i, &h)| {
            if !h.is_finite() {
                return f32::NAN;
            }
            let [x, y] = grid.centre(i / grid.width, i % grid.width);
            let p = [x, y, h as f64];
            views
                .iter()
                .filter(|v| crate::data::camera::project_point(&v.camera, v.origin, &v.rot, p).is_some())
                .count() as f32
        })
        .collect()
}

/// `<product stem>_views.tif`: per cell the training views that saw it ([`view_counts`]), float32 on the product's
/// `w` x `h` grid (nodata NaN); `label` names the source.
pub fn write_views(
    product: &Path,
    counts: Vec<f32>,
    (w, h): (usize, usize),
    georef: &GeoReference,
    label: &str,
) -> Result<PathBuf, SurveyError> {
    let path = sibling(product, "_views.tif");
    let img = SpectralImage::single(w, h, band("views", None, None), counts)?;
    let opts = GeoTiffOptions {
        nodata: Some(f64::NAN),
        georef: Some(*georef),
        bigtiff: None,
        metadata: vec![
            ("msnerf_product".into(), "training views whose image holds each DSM cell's surface point".into()),
            ("msnerf_run".into(), label.into()),
        ],
    };
    crate::output::raster::geotiff::write_geotiff(&path, &img, &opts)?;
    Ok(path)
}

/// The row blocks' consumer handed to a survey renderer.
pub type RowSink<'a> = dyn FnMut(&RowBlock) -> Result<(), SurveyError> + 'a;

/// Renders `grid` once with `run` and writes every product `outputs` asks for.
pub fn export_survey(
    run: &mut LoadedRun,
    grid: &SurveyGrid,
    opts: &SurveyOptions,
    outputs: &SurveyOutputs,
    progress: impl FnMut(usize),
) -> Result<SurveyReport, SurveyError> {
    let top = opts.top.unwrap_or_else(|| median_camera_height(run));
    let source = SurveySource {
        bands: run.ds.bands.clone(),
        crs: run.ds.crs.clone(),
        label: run.dir.display().to_string(),
        top,
        views: training_views(&run.ds),
    };
    write_products(&source, grid, opts, outputs, |opts, sink| render_survey(run, grid, opts, sink, progress))
}

/// Writes every product `outputs` asks for from the row blocks `render` produces (given the options it must render
/// with: without the DSM's filters when no DSM is asked for, and with `top` set). Paths and index bands are checked
/// before `render` is called.
pub fn write_products(
    source: &SurveySource,
    grid: &SurveyGrid,
    opts: &SurveyOptions,
    outputs: &SurveyOutputs,
    render: impl FnOnce(&SurveyOptions, &mut RowSink<'_>) -> Result<SurveyStats, SurveyError>,
) -> Result<SurveyReport, SurveyError> {
    if let Some(p) = &outputs.dsm {
        check_path(p, "--out (dsm)")?;
    }
    if let Some(p) = &outputs.ortho {
        check_path(p, "--out (ortho)")?;
    }
    if let (Some(d), Some(o)) = (&outputs.dsm, &outputs.ortho) {
        if d == o {
            return Err(SurveyError::Invalid {
                what: "--ortho / --dsm".into(),
                reason: format!("the DSM and the ortho would both be written to {}", d.display()),
            });
        }
    }
    if outputs.dsm.is_none() && outputs.ortho.is_none() {
        return Err(SurveyError::Invalid {
            what: "outputs".into(),
            reason: "neither a DSM nor an ortho asked for".into(),
        });
    }
    let bands = source.bands.clone();
    let mut index_inputs = Vec::new();
    for &ix in &outputs.indices {
        if outputs.ortho.is_none() {
            return Err(SurveyError::Invalid { what: "--indices".into(), reason: "indices need the ortho".into() });
        }
        index_inputs.push((ix, bands_for_index(&bands, ix, DEFAULT_TOLERANCE_NM)?));
    }
    let mut opts = opts.clone();
    if outputs.dsm.is_none() {
        // The spread and consistency filters decide the DSM's nodata only; an ortho alone does not pay for them.
        opts.max_spread_cells = None;
        opts.consistency = None;
        opts.refine = None;
    }
    let top = source.top;
    opts.top = Some(top);
    let georef = GeoReference::in_crs(grid.origin, [grid.gsd, grid.gsd], source.crs.as_ref())?;
    let cog = |product: String| CogOptions {
        geotiff: GeoTiffOptions {
            nodata: Some(NODATA),
            georef: Some(georef),
            bigtiff: None,
            metadata: vec![
                ("msnerf_product".into(), product),
                ("msnerf_run".into(), source.label.clone()),
                ("vertical_rays_from_z".into(), format!("{top}")),
                ("min_accumulation".into(), format!("{}", opts.min_accumulation.max(0.5))),
            ],
        },
        preview_max: PREVIEW_MAX,
    };
    let (w, h) = (grid.width, grid.height);
    let dsm = match &outputs.dsm {
        Some(p) => Some(CogWriter::create(
            p,
            w,
            h,
            vec![band("height", None, None)],
            &cog("DSM: first-surface height (world z) seen straight down".into()),
        )?),
        None => None,
    };
    let mut ortho = match &outputs.ortho {
        Some(p) => Some(CogWriter::create(
            p,
            w,
            h,
            bands.clone(),
            &cog("true orthomosaic: band values seen straight down".into()),
        )?),
        None => None,
    };
    let mut index_writers = Vec::new();
    if let Some(o) = &outputs.ortho {
        for (ix, inputs) in &index_inputs {
            let used: Vec<String> = inputs.iter().map(|&b| band_description(&bands[b])).collect();
            let mut c = cog(format!("vegetation index {} of the true orthomosaic", ix.name()));
            c.geotiff.metadata.push(("INDEX".into(), ix.name().into()));
            c.geotiff.metadata.push(("INDEX_BANDS".into(), used.join(", ")));
            let path = sibling(o, &format!("_{}.tif", ix.name().to_lowercase()));
            index_writers.push((
                *ix,
                inputs.clone(),
                path.clone(),
                CogWriter::create(&path, w, h, vec![band(ix.name(), None, None)], &c)?,
            ));
        }
    }
    let nb = bands.len();
    let nd = NODATA as f32;
    // The DSM is held whole (4 + 1 bytes a cell) until its gaps are filled, then written.
    let mut dsm_cells: Vec<f32> = Vec::new();
    let mut dsm_quality: Vec<u8> = Vec::new();
    let mut stats = render(&opts, &mut |block: &RowBlock| {
        if dsm.is_some() {
            dsm_cells.extend_from_slice(&block.height);
            dsm_quality.extend_from_slice(&block.quality);
        }
        if let Some(wr) = ortho.as_mut() {
            let rows: Vec<f32> = block.values.iter().map(|&v| if v.is_finite() { v } else { nd }).collect();
            wr.push_rows(&rows)?;
        }
        for (ix, inputs, _, wr) in index_writers.iter_mut() {
            let mut v = vec![0.0f64; inputs.len()];
            let rows: Vec<f32> = block
                .values
                .chunks_exact(nb)
                .map(|px| {
                    for (k, &b) in inputs.iter().enumerate() {
                        v[k] = px[b] as f64;
                    }
                    let x = ix.formula(&v);
                    if x.is_finite() {
                        x as f32
                    } else {
                        nd
                    }
                })
                .collect();
            wr.push_rows(&rows)?;
        }
        Ok(())
    })?;
    let mut files = Vec::new();
    let mut notes = Vec::new();
    if let (Some(mut wr), Some(path)) = (dsm, &outputs.dsm) {
        let max_cells = opts.fill_max_distance.map_or(FILL_MAX_CELLS, |d| d / grid.gsd);
        let rise = crate::output::raster::fill::MAX_SLOPE * grid.gsd;
        let fill = FillParams { mode: opts.fill, max_cells, max_rise_per_cell: rise, tolerance: opts.fill_tolerance };
        finish_dsm(&mut dsm_cells, &mut dsm_quality, w, h, &fill, opts.refine.is_some(), &mut stats);
        let rows: Vec<f32> = dsm_cells.iter().map(|&z| if z.is_finite() { z } else { nd }).collect();
        wr.push_rows(&rows)?;
        let pv = wr.finish()?;
        files.push(path.clone());
        if let Some(pv) = pv {
            files.extend(dsm_previews(path, &pv, grid.gsd)?);
        }
        let what = "DSM quality: 1 measured, 2 interpolated, 3 field only, 0 nodata";
        files.extend(write_quality(path, &dsm_quality, w, h, &georef, what, &source.label)?);
        if !source.views.is_empty() {
            let counts = view_counts(&dsm_cells, grid, &source.views);
            files.push(write_views(path, counts, (w, h), &georef, &source.label)?);
        }
    }
    if let (Some(wr), Some(path)) = (ortho, &outputs.ortho) {
        let pv = wr.finish()?;
        files.push(path.clone());
        if let Some(pv) = pv {
            let (f, n) = ortho_previews(path, &pv)?;
            files.extend(f);
            notes.extend(n);
        }
    }
    for (ix, _, path, wr) in index_writers {
        let pv = wr.finish()?;
        files.push(path.clone());
        if let Some(pv) = pv {
            let img = without_nodata(pv.image);
            let png = path.with_extension("png");
            preview::index_preview(&img.data, img.width, img.height, ix.preview_range())?.write_png(&png)?;
            files.push(png);
        }
    }
    Ok(SurveyReport { grid: *grid, stats, files, notes })
}

/// How [`finish_dsm`] fills: the mode, the distance in cells and the steepest rise per cell an interpolation may
/// bridge ([`crate::output::raster::fill`]), and [`DsmFill::Auto`]'s tolerance in world units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FillParams {
    pub mode: DsmFill,
    pub max_cells: f64,
    pub max_rise_per_cell: f64,
    pub tolerance: f64,
}

/// The DSM's final heights and quality codes: the cells without photometric support (when the refinement ran) and
/// the surfaces the filters turned down are filled, kept or dropped as `fill` says; `stats` counts the outcome.
pub fn finish_dsm(
    z: &mut [f32],
    q: &mut [u8],
    w: usize,
    h: usize,
    fill: &FillParams,
    refined: bool,
    stats: &mut SurveyStats,
) {
    // Without the refinement nothing is measured photometrically: the field's consistent heights are what there is.
    let source_code = if refined { quality::MEASURED } else { quality::FIELD_ONLY };
    let unsupported = |c: u8| c == quality::GAP || (refined && c == quality::FIELD_ONLY);
    match fill.mode {
        DsmFill::Field => {}
        DsmFill::None => {
            for (zi, qi) in z.iter_mut().zip(q.iter_mut()) {
                if *qi == quality::FIELD_ONLY && refined {
                    *zi = f32::NAN;
                    *qi = quality::NODATA;
                }
            }
        }
        DsmFill::Interpolate | DsmFill::Auto => {
            let source: Vec<bool> = q.iter().map(|&c| c == source_code).collect();
            let want: Vec<bool> = q.iter().map(|&c| unsupported(c)).collect();
            let filled =
                crate::output::raster::fill::fill_idw(z, &source, &want, w, h, fill.max_cells, fill.max_rise_per_cell);
            for ((zi, qi), f) in z.iter_mut().zip(q.iter_mut()).zip(filled) {
                if !unsupported(*qi) {
                    continue;
                }
                // Auto takes the interpolation for an unsupported cell only where the field's height agrees with
                // it, and for a gap unless it lies above the height the gap was turned down with (the field errs
                // upwards, with floaters; an interpolation above it bridges a step down, as from a roof over the
                // foot of its wall). Otherwise an unsupported cell keeps the field's height, a gap stays a gap.
                let tol = fill.tolerance;
                let disagrees = fill.mode == DsmFill::Auto
                    && f.is_none_or(|v| {
                        // NaN (a gap turned down without a height) disagrees.
                        let above = (v - *zi) as f64;
                        let off = if *qi == quality::GAP { above } else { above.abs() };
                        off.is_nan() || off > tol
                    });
                match f {
                    _ if disagrees && *qi == quality::FIELD_ONLY => {}
                    _ if disagrees => {
                        *zi = f32::NAN;
                        *qi = quality::NODATA;
                    }
                    Some(v) => {
                        *zi = v;
                        *qi = quality::INTERPOLATED;
                    }
                    None => {
                        *zi = f32::NAN;
                        *qi = quality::NODATA;
                    }
                }
            }
        }
    }
    for (zi, qi) in z.iter_mut().zip(q.iter_mut()) {
        if *qi == quality::GAP {
            *zi = f32::NAN;
            *qi = quality::NODATA;
        }
    }
    let count = |c: u8| q.iter().filter(|&&x| x == c).count();
    stats.measured = count(quality::MEASURED);
    stats.interpolated = count(quality::INTERPOLATED);
    stats.field_only = count(quality::FIELD_ONLY);
    stats.valid = stats.measured + stats.interpolated + stats.field_only;
}

/// Colours of the quality preview: nodata, measured, interpolated, field only.
pub const QUALITY_COLOURS: [[u8; 3]; 4] = [[0, 0, 0], [46, 160, 67], [240, 200, 40], [220, 90, 40]];

/// `<product stem>_quality.tif` (the codes of [`quality`] as float32, nodata 0, on the product's grid; no overviews,
/// as categories do not average) and its PNG preview; `what` says what the codes mean, `label` names the source.
pub fn write_quality(
    dsm: &Path,
    q: &[u8],
    w: usize,
    h: usize,
    georef: &GeoReference,
    what: &str,
    label: &str,
) -> Result<Vec<PathBuf>, SurveyError> {
    let path = sibling(dsm, "_quality.tif");
    let img = SpectralImage {
        width: w,
        height: h,
        bands: vec![band("quality", None, None)],
        data: q.iter().map(|&c| f32::from(c)).collect(),
    };
    let opts = GeoTiffOptions {
        nodata: Some(0.0),
        georef: Some(*georef),
        bigtiff: None,
        metadata: vec![("msnerf_product".into(), what.into()), ("msnerf_run".into(), label.into())],
    };
    crate::output::raster::geotiff::write_geotiff(&path, &img, &opts)?;
    // A preview of at most PREVIEW_MAX on its longer side (nearest cell).
    let step = w.max(h).div_ceil(PREVIEW_MAX).max(1);
    let (pw, ph) = (w.div_ceil(step), h.div_ceil(step));
    let mut png = preview::Rgb8::filled(pw, ph, QUALITY_COLOURS[0]);
    for y in 0..ph {
        for x in 0..pw {
            let c = q[(y * step) * w + x * step] as usize;
            png.put(x, y, QUALITY_COLOURS[c.min(3)]);
        }
    }
    let png_path = path.with_extension("png");
    png.write_png(&png_path)?;
    Ok(vec![path, png_path])
}

/// The preview image with nodata as NaN (the preview functions paint NaN black).
pub fn without_nodata(mut img: SpectralImage) -> SpectralImage {
    img.data.iter_mut().filter(|v| **v == NODATA as f32).for_each(|v| *v = f32::NAN);
    img
}

/// [`height_previews`] of a height COG's preview level (`gsd`: the full resolution's cell size).
pub fn dsm_previews(path: &Path, pv: &CogPreview, gsd: f64) -> Result<Vec<PathBuf>, SurveyError> {
    height_previews(path, &without_nodata(pv.image.clone()), gsd * pv.factor as f64)
}

/// `<stem>_hillshade.png` and `<stem>_height.png` (turbo over the 2nd-98th percentile, with a colour bar) of a
/// height image (NaN = nodata) with cells of `gsd`.
pub fn height_previews(path: &Path, img: &SpectralImage, gsd: f64) -> Result<Vec<PathBuf>, SurveyError> {
    let (w, h) = (img.width, img.height);
    let grey = hillshade(&img.data, w, h, gsd, Sun::default());
    let shade = Rgb8 { width: w, height: h, data: grey.iter().flat_map(|&g| [g, g, g]).collect() };
    let shade_path = sibling(path, "_hillshade.png");
    shade.write_png(&shade_path)?;
    let range = (preview::percentile(&img.data, 2.0), preview::percentile(&img.data, 98.0));
    let height =
        preview::with_colorbar(&preview::colormapped(&img.data, w, h, Colormap::Turbo, range)?, Colormap::Turbo);
    let height_path = sibling(path, "_height.png");
    height.write_png(&height_path)?;
    Ok(vec![shade_path, height_path])
}

fn ortho_previews(path: &Path, pv: &CogPreview) -> Result<(Vec<PathBuf>, Vec<String>), SurveyError> {
    band_previews(path, &without_nodata(pv.image.clone()))
}

/// `<stem>_rgb.png`, `<stem>_cir.png` and `<stem>_ndvi.png` of a multi-band image (NaN = nodata), where its bands'
/// wavelengths allow; the others are returned as notes.
pub fn band_previews(path: &Path, img: &SpectralImage) -> Result<(Vec<PathBuf>, Vec<String>), SurveyError> {
    let img = img.clone();
    let (mut files, mut notes) = (Vec::new(), Vec::new());
    let stretch = Stretch::default();
    for (suffix, made) in [
        ("_rgb.png", preview::natural_colour(&img, stretch)),
        ("_cir.png", preview::cir(&img, stretch)),
        (
            "_ndvi.png",
            crate::output::raster::compute_index(&img, VegetationIndex::Ndvi, DEFAULT_TOLERANCE_NM)
                .and_then(|v| preview::index_preview(&v, img.width, img.height, VegetationIndex::Ndvi.preview_range())),
        ),
    ] {
        match made {
            Ok(rgb) => {
                let p = sibling(path, suffix);
                rgb.write_png(&p)?;
                files.push(p);
            }
            Err(e) => notes.push(format!("{}: not written: {e}", sibling(path, suffix).display())),
        }
    }
    Ok((files, notes))
}
