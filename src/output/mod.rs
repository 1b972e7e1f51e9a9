//! Outputs layer: everything a user takes home from a trained model, on the CPU, from plain arrays.
//!
//! - [`image`]: [`SpectralImage`], a band-planar f32 image with its band metadata (the input of every raster output).
//! - [`metrics`]: PSNR, SSIM (scikit-image's Gaussian convention, exactly), and the `ns-eval`-style [`EvalReport`].
//! - [`raster`]: multi-band float32 GeoTIFF with GDAL band descriptions, EXR, PNG previews (natural colour, CIR,
//!   index colour maps, depth, accumulation, error), contact sheets, and vegetation indices by wavelength.
//! - [`pointcloud`]: [`PointCloud`] with per-band reflectance; PLY and LAS 1.4 (PDRF 8 + Extra Bytes) writers
//!   and readers; statistical outlier removal, crop boxes, deterministic subsampling.
//! - [`compare`]: cloud-to-cloud accuracy/completeness/F-score and per-band reflectance error (`msnerf compare-cloud`).
//! - [`compare_raster`]: DSM / orthomosaic against a reference raster, per band and per class (`msnerf compare-raster`).
//!
//! Every file is written atomically ([`atomic`]): a temporary file in the same folder, renamed on success.
//! Bad input is an [`OutputError`] naming the file or the parameter, never a panic.

pub use crate::util::atomic;
pub mod compare;
pub mod compare_raster;
pub mod error;
pub mod image;
pub mod metrics;
pub mod pointcloud;
pub mod raster;

pub use compare::{compare_clouds, CompareOptions, CompareReport};
pub use error::OutputError;
pub use image::SpectralImage;
pub use metrics::{EvalReport, ImageMetrics, MetricOptions, ViewEval};
pub use pointcloud::PointCloud;

/// The band type shared with the data layer (name, centre wavelength, FWHM).
pub use crate::data::Band;

/// Result type of the outputs layer.
pub type Result<T> = std::result::Result<T, OutputError>;
