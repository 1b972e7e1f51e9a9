//! Pose import (`msnerf import poses`): camera poses, intrinsics and sparse points from photogrammetry tools into
//! a dataset. docs/poses.md gives each tool's conventions.
//!
//! - [`model`]: the tool-independent form (OpenGL camera-to-world, msnerf camera keys, points);
//! - [`colmap`]: COLMAP sparse models (text and binary); [`opensfm`]: OpenSfM reconstructions and ODM projects;
//!   [`metashape`]: Agisoft Metashape camera XML;
//! - [`apply`]: matching model images to frames and rewriting the dataset (backup kept, atomic writes).

pub mod apply;
pub mod colmap;
pub mod colmap_rigs;
pub mod error;
pub mod metashape;
pub mod model;
pub mod opensfm;

pub use apply::{apply_poses, apply_poses_to, read_transforms, transforms_path, PoseImportReport};
pub use model::PoseModel;

pub use error::PoseError;
