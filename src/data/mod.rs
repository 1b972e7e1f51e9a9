//! Data layer: multispectral datasets (spec/dataset.md) read into memory without losing bit depth.
//!
//! - [`error`]: `DataError`, naming the file and the key or frame of every problem.
//! - [`raster`]: compact in-memory images (u8/u16/u32/f16/f32), scaled to f32 only on access.
//! - [`reader`], [`tiff_reader`], [`exr_reader`], [`png_reader`], [`xmp`]: file decoders.
//! - [`transforms`], [`split`], [`loader`]: `transforms.json` to a [`loader::Dataset`].
//! - [`pose`]: nerfstudio-style pose normalisation in f64 ([`pose::PoseTransform`]).
//! - [`camera`]: camera models and CPU ray generation (f32 and f64 twins of the GPU kernel).
//! - [`cache`]: host image cache with a byte budget and pixel sampling.
//! - [`check`]: `dataset check` as a library function.
//! - [`bench`]: cache/load benchmark.
//! - [`outliers`]: implausible camera centres (refused by name, or dropped with `drop_outliers`).
//! - [`rig_cameras`]: per-band cameras of a multi-camera rig (`rig_cameras`), for rig-aware training.
//! - [`sparse_points`]: `sparse_points_path`, SfM-like points with the frames that observed them.

pub mod aerial;
pub mod bench;
pub mod cache;
pub mod camera;
pub mod check;
pub mod error;
pub mod exr_reader;
pub mod loader;
pub mod outliers;
pub mod png_reader;
pub mod pose;
pub mod pose_build;
pub mod raster;
pub mod reader;
pub mod rig_cameras;
pub mod sparse_points;
pub mod split;
pub mod synth;
pub mod tiff_reader;
pub mod transforms;
pub mod xmp;

pub use cache::{CacheConfig, ImageCache, PixelBatch};
pub use camera::{Camera, CameraModel, Distortion, Ray};
pub use check::{check_dataset, CheckReport};
pub use error::{DataError, FrameRef};
pub use loader::{load_dataset, AlphaBackground, Band, BandSelection, Dataset, Frame, ImageSource, LoadOptions};
pub use pose::{PoseNormalization, PoseTransform};
pub use raster::{Alpha, Raster, SampleType, Samples};
pub use split::Split;
