//! Raster outputs: float32 GeoTIFF with GDAL band descriptions ([`geotiff`]), multi-channel EXR ([`exr`]),
//! 8-bit PNG previews ([`preview`], [`colormap`]), contact sheets ([`contact`]) and vegetation indices by
//! centre wavelength ([`indices`]).

pub mod colormap;
pub mod contact;
pub mod exr;
pub mod geotiff;
pub mod indices;
pub mod preview;

pub use colormap::Colormap;
pub use contact::{contact_sheet, Tile};
pub use exr::write_exr;
pub use geotiff::{write_geotiff, GeoReference, GeoTiffOptions};
pub use indices::{compute_index, write_index_geotiff, VegetationIndex};
pub use preview::{Rgb8, Stretch};
