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

/// Reads a COLMAP model folder and puts it into the dataset.
pub fn import_colmap(model_dir: &std::path::Path, dataset: &std::path::Path) -> Result<PoseImportReport, PoseError> {
    let m = colmap::read_model(model_dir)?;
    apply_poses(&colmap::to_pose_model(&m, model_dir)?, model_dir, dataset)
}
pub use error::PoseError;
