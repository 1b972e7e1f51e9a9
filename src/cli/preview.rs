//! `msnerf preview RASTER.tif`: the PNG previews the survey exports write, for any north-up GeoTIFF (a reference
//! LiDAR DSM, the simulator's `truth/dsm.tif` and `truth/ortho.tif`): one band is a height grid (`<stem>_hillshade.png`,
//! `<stem>_height.png`), several bands with wavelengths an image (`<stem>_rgb.png`, `_cir.png`, `_ndvi.png` where
//! the bands allow). Reads the whole raster: meant for rasters that fit in memory.

use std::path::PathBuf;

use crate::nerf::survey_products::{band_previews, height_previews};
use crate::output::raster::geotiff_read::read_geotiff;
use crate::output::SpectralImage;

#[derive(clap::Args, Debug)]
pub struct PreviewArgs {
    /// The GeoTIFF
    pub raster: PathBuf,
}

pub fn run(a: &PreviewArgs) -> anyhow::Result<()> {
    let r = read_geotiff(&a.raster)?;
    let g = &r.grid;
    let mut data = r.data.clone();
    data.iter_mut().filter(|v| r.is_nodata(**v)).for_each(|v| *v = f32::NAN);
    let bands = if let Some(names) = (!g.descriptions.is_empty()).then_some(&g.descriptions) {
        names.iter().map(|d| crate::output::image::band_from_description(d)).collect()
    } else {
        (0..g.bands).map(|b| crate::output::image::band(&format!("band {}", b + 1), None, None)).collect()
    };
    let img = SpectralImage::from_planar(g.width, g.height, bands, data)?;
    let files = if g.bands == 1 {
        height_previews(&a.raster, &img, g.pixel_size[0])?
    } else {
        let (files, notes) = band_previews(&a.raster, &img)?;
        notes.iter().for_each(|n| println!("note: {n}"));
        files
    };
    files.iter().for_each(|f| println!("-> {}", f.display()));
    Ok(())
}
