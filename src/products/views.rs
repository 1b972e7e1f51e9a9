//! The per-view products of a rendered view (`msnerf render`, `demo`, `render BLOCKS`): a multi-band float32
//! GeoTIFF with band names, an optional EXR, PNG previews (natural colour, CIR, vegetation indices with a colour
//! bar, depth, accumulation, the error against the frame's image when there is one), the indices as float
//! GeoTIFFs, and a contact sheet of the previews. Every caller writes the same files through these functions.

use std::path::Path;

use super::ProductError;
use crate::data::Band;
use crate::nerf::evaluate::ground_truth;
use crate::nerf::run::{LoadedRun, RenderedView};
use crate::output::image::SpectralImage;
use crate::output::raster::colormap::Colormap;
use crate::output::raster::contact::{contact_sheet, Tile};
use crate::output::raster::geotiff::{write_geotiff, GeoTiffOptions};
use crate::output::raster::indices::{
    bands_for_index, compute_index, write_index_geotiff, VegetationIndex, DEFAULT_TOLERANCE_NM,
};
use crate::output::raster::preview::{self, Rgb8, Stretch};

/// What to write for each view.
#[derive(Debug, Clone)]
pub struct ViewOptions {
    pub exr: bool,
    pub indices: Vec<VegetationIndex>,
    pub stretch: Stretch,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions { exr: false, indices: vec![VegetationIndex::Ndvi], stretch: Stretch::Reflectance }
    }
}

/// The preview stretch by name: `reflectance` (fixed ranges) or `percentile` (2-98 %).
pub fn parse_stretch(s: &str) -> Result<Stretch, ProductError> {
    match s {
        "reflectance" => Ok(Stretch::Reflectance),
        "percentile" => Ok(Stretch::Percentile { low: 2.0, high: 98.0 }),
        _ => Err(ProductError::option("--stretch", format!("expected `reflectance` or `percentile`, got `{s}`"))),
    }
}

/// Each index of `o` has the bands it needs among `bands` (checked before anything is rendered or written).
pub fn check_index_bands(bands: &[Band], o: &ViewOptions) -> Result<(), ProductError> {
    let bands: Vec<_> = bands.iter().map(|b| crate::output::image::band(&b.name, b.center_nm, b.fwhm_nm)).collect();
    for idx in &o.indices {
        bands_for_index(&bands, *idx, DEFAULT_TOLERANCE_NM)
            .map_err(|e| ProductError::option("--indices", format!("{}: {e}", idx.name())))?;
    }
    Ok(())
}

/// The previews of one written view, labelled, for the contact sheet.
pub struct ViewFiles {
    pub tiles: Vec<(String, Rgb8)>,
}

/// Renders dataset frame `frame`, writes everything for it into `out` and returns its preview tiles.
pub fn write_view(run: &mut LoadedRun, frame: usize, out: &Path, o: &ViewOptions) -> Result<ViewFiles, ProductError> {
    let rv = run.render_view(frame)?;
    let stem = Path::new(&run.ds.frames[frame].name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or(format!("view{frame}"));
    // With `rig_cameras` the image holds each band in its own camera, not the frame camera's registered view: an
    // error map against it would show the rig's parallax as model error, so there is none.
    let gt = if run.ds.rig.is_some() { None } else { ground_truth(run, frame).ok().map(|(gt, _)| gt) };
    write_outputs(&run.ds.bands, &rv, &stem, gt.as_ref(), out, o)
}

/// Renders novel view `k` (set with [`LoadedRun::set_novel_views`]) and writes its files, without an error map.
pub fn write_novel_view(run: &mut LoadedRun, k: usize, out: &Path, o: &ViewOptions) -> Result<ViewFiles, ProductError> {
    let rv = run.render_novel_view(k)?;
    let stem = run.novel[k].name.clone();
    write_outputs(&run.ds.bands, &rv, &stem, None, out, o)
}

/// Writes the files of one rendered view named `stem`; `gt` (the frame's image) adds the error preview.
pub fn write_outputs(
    bands: &[Band],
    rv: &RenderedView,
    stem: &str,
    gt: Option<&SpectralImage>,
    out: &Path,
    o: &ViewOptions,
) -> Result<ViewFiles, ProductError> {
    let img = SpectralImage::from_interleaved(rv.width, rv.height, bands.to_vec(), &rv.colour)?;
    write_geotiff(&out.join(format!("{stem}.tif")), &img, &GeoTiffOptions::default())?;
    if o.exr {
        crate::output::raster::exr::write_exr(&out.join(format!("{stem}.exr")), &img)?;
    }
    let mut tiles = Vec::new();
    let mut save = |name: &str, png: Rgb8| -> Result<(), ProductError> {
        png.write_png(&out.join(format!("{stem}_{name}.png")))?;
        tiles.push((format!("{stem} {name}"), png));
        Ok(())
    };
    // Natural colour and CIR need the visible / NIR bands; a dataset without them simply has no such preview.
    if let Ok(p) = preview::natural_colour(&img, o.stretch) {
        save("rgb", p)?;
    }
    if let Ok(p) = preview::cir(&img, o.stretch) {
        save("cir", p)?;
    }
    for idx in &o.indices {
        let name = idx.name().to_lowercase();
        write_index_geotiff(&out.join(format!("{stem}_{name}.tif")), &img, *idx, DEFAULT_TOLERANCE_NM, None)?;
        let v = compute_index(&img, *idx, DEFAULT_TOLERANCE_NM)?;
        let p = preview::with_colorbar(
            &preview::index_preview(&v, rv.width, rv.height, idx.preview_range())?,
            Colormap::RdYlGn,
        );
        save(&name, p)?;
    }
    save("depth", preview::depth_preview(&rv.depth, rv.width, rv.height, None, Colormap::Turbo)?)?;
    save("acc", preview::accumulation_preview(&rv.accumulation, rv.width, rv.height)?)?;
    if let Some(gt) = gt {
        save("error", preview::error_preview(&img, gt, None)?.0)?;
    }
    Ok(ViewFiles { tiles })
}

/// The contact sheet of `tiles` (`per_view` previews a row) as `out/contact_sheet.png`.
pub fn write_contact_sheet(tiles: &[(String, Rgb8)], per_view: usize, out: &Path) -> Result<(), ProductError> {
    let t: Vec<Tile> = tiles.iter().map(|(l, i)| Tile { image: i, label: Some(l.as_str()) }).collect();
    contact_sheet(&t, per_view.max(1), 4, [32, 32, 32])?.write_png(&out.join("contact_sheet.png"))?;
    Ok(())
}
