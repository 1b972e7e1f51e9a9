//! `msnerf render RUN --views eval|train|all --out DIR`: per view a multi-band float32 GeoTIFF with band names (GDAL
//! metadata), optional EXR, PNG previews (natural colour, CIR, NDVI with a colour bar, depth, accumulation, error
//! against ground truth), vegetation indices chosen by name as float GeoTIFFs, and a contact sheet.

use super::eval::{ground_truth, parse_split};
use super::Cli;
use crate::data::Split;
use crate::gpu::Context;
use crate::nerf::run::LoadedRun;
use crate::output::image::SpectralImage;
use crate::output::raster::colormap::Colormap;
use crate::output::raster::contact::{contact_sheet, Tile};
use crate::output::raster::geotiff::{write_geotiff, GeoTiffOptions};
use crate::output::raster::indices::{compute_index, write_index_geotiff, VegetationIndex};
use crate::output::raster::preview::{self, Rgb8, Stretch};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Run folder written by `msnerf train`
    pub run: PathBuf,
    /// Views to render: eval, train or all
    #[arg(long, default_value = "eval")]
    pub views: String,
    /// Output folder
    #[arg(long)]
    pub out: PathBuf,
    /// Also write an OpenEXR per view
    #[arg(long)]
    pub exr: bool,
    /// Vegetation indices to write as float GeoTIFFs (comma separated, e.g. NDVI,NDRE720,GNDVI)
    #[arg(long, value_delimiter = ',', default_value = "NDVI")]
    pub indices: Vec<String>,
    /// Preview stretch: `reflectance` (fixed 0-0.5 visible, 0-0.8 NIR) or `percentile` (2-98 %)
    #[arg(long, default_value = "reflectance")]
    pub stretch: String,
    /// At most this many views in the contact sheet
    #[arg(long, default_value_t = 8)]
    pub sheet_views: usize,
}

/// Previews and files of one rendered view; returns the tiles for the contact sheet.
pub struct ViewFiles {
    pub tiles: Vec<(String, Rgb8)>,
}

fn stretch(s: &str) -> anyhow::Result<Stretch> {
    match s {
        "reflectance" => Ok(Stretch::Reflectance),
        "percentile" => Ok(Stretch::Percentile { low: 2.0, high: 98.0 }),
        _ => anyhow::bail!("--stretch: expected `reflectance` or `percentile`, got `{s}`"),
    }
}

/// Writes everything for one view into `out` and returns its preview tiles.
pub fn write_view(run: &mut LoadedRun, frame: usize, out: &Path, a: &RenderArgs) -> anyhow::Result<ViewFiles> {
    let rv = run.render_view(frame).map_err(anyhow::Error::msg)?;
    let stem = Path::new(&run.ds.frames[frame].name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or(format!("view{frame}"));
    let img = SpectralImage::from_interleaved(rv.width, rv.height, run.ds.bands.clone(), &rv.colour)?;
    write_geotiff(&out.join(format!("{stem}.tif")), &img, &GeoTiffOptions::default())?;
    if a.exr {
        crate::output::raster::exr::write_exr(&out.join(format!("{stem}.exr")), &img)?;
    }
    let st = stretch(&a.stretch)?;
    let mut tiles = Vec::new();
    let mut save = |name: &str, png: Rgb8| -> anyhow::Result<()> {
        png.write_png(&out.join(format!("{stem}_{name}.png")))?;
        tiles.push((format!("{stem} {name}"), png));
        Ok(())
    };
    // Natural colour and CIR need the visible / NIR bands; a dataset without them simply has no such preview.
    if let Ok(p) = preview::natural_colour(&img, st) {
        save("rgb", p)?;
    }
    if let Ok(p) = preview::cir(&img, st) {
        save("cir", p)?;
    }
    for name in &a.indices {
        let idx = VegetationIndex::parse(name)?;
        write_index_geotiff(&out.join(format!("{stem}_{}.tif", idx.name().to_lowercase())), &img, idx, 25.0, None)?;
        let v = compute_index(&img, idx, 25.0)?;
        let p = preview::with_colorbar(
            &preview::index_preview(&v, rv.width, rv.height, idx.preview_range())?,
            Colormap::RdYlGn,
        );
        save(&idx.name().to_lowercase(), p)?;
    }
    save("depth", preview::depth_preview(&rv.depth, rv.width, rv.height, None, Colormap::Turbo)?)?;
    save("acc", preview::accumulation_preview(&rv.accumulation, rv.width, rv.height)?)?;
    if let Ok((gt, _)) = ground_truth(run, frame) {
        save("error", preview::error_preview(&img, &gt, None)?.0)?;
    }
    Ok(ViewFiles { tiles })
}

pub fn run(cli: &Cli, a: &RenderArgs) -> anyhow::Result<()> {
    // Check every flag before rendering anything, so a typo does not leave a half-filled output folder.
    for name in &a.indices {
        VegetationIndex::parse(name)?;
    }
    stretch(&a.stretch)?;
    let ctx = Context::new(&cli.context_desc())?;
    let mut run = LoadedRun::load(&ctx, &a.run).map_err(anyhow::Error::msg)?;
    let frames: Vec<usize> = match a.views.as_str() {
        "all" => (0..run.ds.frames.len()).collect(),
        s => run.ds.split_indices(parse_split(s).unwrap_or(Split::Eval)),
    };
    anyhow::ensure!(!frames.is_empty(), "--views {}: no frames", a.views);
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let mut sheet: Vec<(String, Rgb8)> = Vec::new();
    for (k, &f) in frames.iter().enumerate() {
        let v = write_view(&mut run, f, &a.out, a)?;
        if k < a.sheet_views {
            sheet.extend(v.tiles);
        }
        println!("rendered {} ({}/{})", run.ds.frames[f].name, k + 1, frames.len());
    }
    let per_view = sheet.len() / frames.len().min(a.sheet_views).max(1);
    let tiles: Vec<Tile> = sheet.iter().map(|(l, i)| Tile { image: i, label: Some(l.as_str()) }).collect();
    contact_sheet(&tiles, per_view.max(1), 4, [32, 32, 32])?.write_png(&a.out.join("contact_sheet.png"))?;
    println!("outputs in {}", a.out.display());
    Ok(())
}
