//! Pose import (`msnerf import poses`): camera poses, intrinsics and sparse points from photogrammetry tools into
//! a dataset. docs/poses.md gives each tool's conventions.
//!
//! - [`colmap`]: COLMAP sparse models (text and binary) and the pose convention change;
//! - [`apply`]: matching model images to frames and rewriting the dataset (backup kept, atomic writes).

pub mod apply;
pub mod colmap;
pub mod error;

pub use apply::{apply_colmap, PoseImportReport};
pub use error::PoseError;
