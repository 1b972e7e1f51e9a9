//! Raster outputs: float32 GeoTIFF with GDAL band descriptions ([`geotiff`]), streamed Cloud-Optimized GeoTIFF
//! with overviews ([`cog`]), multi-channel EXR ([`exr`]),
//! 8-bit PNG previews ([`preview`], [`colormap`], [`hillshade`]), contact sheets ([`contact`]) and vegetation indices by
//! centre wavelength ([`indices`]).

pub mod cog;
pub mod colormap;
pub mod contact;
pub mod exr;
pub mod fill;
pub mod geotiff;
pub mod geotiff_read;
pub mod hillshade;
pub mod indices;
pub mod preview;

pub use cog::{CogOptions, CogWriter};
pub use colormap::Colormap;
pub use contact::{contact_sheet, Tile};
pub use exr::write_exr;
pub use geotiff::{write_geotiff, GeoReference, GeoTiffOptions};
pub use indices::{compute_index, write_index_geotiff, VegetationIndex};
pub use preview::{Rgb8, Stretch};
