//! Products of a trained run, beside training: the layer the commands (`export`, `process`, `demo`) call, so that
//! every way of making a product makes the same one.
//!
//! - [`cloud`]: the multispectral point cloud's post-filters (crop, statistical outliers, grid thinning, a point
//!   budget), writing (PLY or LAS with the CRS) and its summary;
//! - [`terrain`]: the DTM by SMRF ground filtering of a DSM, and the canopy height model;
//! - [`trees`]: tree tops, crowns and their attributes from a canopy height model;
//! - [`canopy`]: those as files on the DSM's grid (`export dtm`, `export chm`, `export trees`, `process`);
//! - [`survey_grid`]: the grid a DSM or ortho is made on (another raster's, or cells over bounds);
//! - [`views`]: the files of a rendered view (GeoTIFF, EXR, previews, index rasters) and the contact sheet;
//! - [`error`]: [`ProductError`], naming the option or file concerned.
//!
//! The rendering itself (points, DSM and true ortho from the field) is `nerf::export` and `nerf::survey`.

pub mod canopy;
pub mod cloud;
pub mod error;
pub mod survey_grid;
pub mod terrain;
pub mod trees;
pub mod views;

pub use error::ProductError;
