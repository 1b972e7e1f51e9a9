//! `msnerf sfm DATASET`: camera poses for a dataset by running COLMAP for the user (issue 20, item 1), as
//! nerfstudio's `ns-process-data` does, then geo-registering them to the frames' GPS when they have it.
//!
//! 1. [`images`]: one 8-bit PNG per frame (a band chosen for texture, or a panchromatic mix), upsampled when the
//!    images are small (SIFT finds ~100 features in a 256x192 aerial view; COLMAP may not initialise on that);
//! 2. [`colmap`]: `feature_extractor` (the dataset's intrinsics as the camera when the frames share one),
//!    `exhaustive_matcher` (small sets) or `sequential_matcher` (flights), `mapper`; every step's log is kept in
//!    `DATASET/colmap/`, a failing step is named with its log;
//! 3. the largest model is read back (`crate::poses::colmap`), its cameras scaled back to the dataset's pixels;
//! 4. [`georef`]: with GPS fixes (or GPS pose priors) in the frames, a robust similarity fit puts the model in the
//!    dataset's projected CRS (its UTM zone by default); with ground control in the dataset ([`control`]) the points
//!    fix the fit and their residuals are reported;
//! 5. `crate::poses::apply_poses` writes the poses, intrinsics and sparse points into the dataset (the old
//!    `transforms.json` kept as a backup, unregistered frames listed in `unregistered_frames`).

pub mod adjusted;
pub mod bundle;
pub mod colmap;
pub mod control;
pub mod georef;
pub mod images;
pub mod run;

pub use run::{run_sfm, SfmOptions, SfmReport};

/// Errors of `msnerf sfm`: each names the file, the option or the COLMAP step (with its log).
#[derive(Debug, thiserror::Error)]
pub enum SfmError {
    #[error("{}: {reason}", path.display())]
    Dataset { path: std::path::PathBuf, reason: String },
    #[error("option {key}: {reason}")]
    Option { key: String, reason: String },
    #[error("{0}")]
    ColmapMissing(String),
    #[error("COLMAP step `{step}` failed: {reason} (its log: {})", log.display())]
    Step { step: String, reason: String, log: std::path::PathBuf },
    #[error(transparent)]
    Pose(#[from] crate::poses::PoseError),
}
