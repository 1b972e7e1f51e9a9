//! Bare earth from a surface model: the digital terrain model (DTM) by SMRF ground filtering of a DSM, and the canopy
//! height model (CHM = DSM - DTM).
//!
//! - [`grid`]: [`HeightGrid`], a north-up height raster (NaN nodata) and its bilinear sampling;
//! - [`morphology`]: grey-scale erosion, dilation and opening with a disk, row-decomposed;
//! - [`inpaint`]: filling empty cells with the mean of their eight nearest filled cells (SMRF's KNN inpainting);
//! - [`smrf`]: the Simple Morphological Filter (Pingel, Clarke and McBride 2013), as PDAL's `filters.smrf`;
//! - [`chm`]: the canopy height model.

pub mod chm;
pub mod grid;
pub mod inpaint;
pub mod morphology;
pub mod smrf;

pub use chm::canopy_height;
pub use grid::HeightGrid;
pub use smrf::{smrf, Smrf, SmrfParams};
