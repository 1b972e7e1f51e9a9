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

/// The tools poses come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseFormat {
    /// A COLMAP sparse model folder (text or binary: cameras, images, points3D)
    Colmap,
    /// An OpenSfM reconstruction.json (tracks.csv beside it gives the points' tracks)
    Opensfm,
    /// An OpenDroneMap project folder (opensfm/reconstruction.json plus odm_georeferencing/coords.txt)
    Odm,
    /// An Agisoft Metashape camera XML (File > Export > Export Cameras)
    Metashape,
}

impl PoseFormat {
    /// Reads the tool's model at `path` (`crs`: the projected CRS of a georeferenced Metashape chunk).
    pub fn read(self, path: &std::path::Path, crs: Option<&crate::geo::Crs>) -> Result<PoseModel, PoseError> {
        Ok(match self {
            PoseFormat::Colmap => {
                let m = colmap::read_model(path)?;
                colmap::to_pose_model(&m, path)?
            }
            PoseFormat::Opensfm => opensfm::read_reconstruction(path)?,
            PoseFormat::Odm => opensfm::read_odm(path)?,
            PoseFormat::Metashape => metashape::read_cameras_xml(path, crs)?,
        })
    }
}
