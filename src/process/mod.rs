//! `msnerf process FLIGHT --out PROJECT`: the flight from the camera's card to the survey products in one command,
//! as OpenDroneMap users expect: import -> poses (COLMAP, or another tool's) -> dataset check -> training with the
//! hardware's profile and depth supervision from the sparse points -> held-out evaluation -> point cloud -> DSM,
//! true ortho and index rasters -> the processing report. Each stage is resumable and skipped when current
//! ([`stage`]); the per-step commands stay for experts and call the same library functions.
//!
//! - [`run`]: the options and the loop over the stages; [`stages`]: each stage; [`stage`]: records and freshness;
//! - [`report`]: the HTML report; [`error`]: [`ProcessError`].

pub mod error;
pub mod report;
pub mod run;
pub mod stage;
pub mod stages;

pub use error::ProcessError;
pub use run::{process, ProcessOptions, ProcessSummary};
pub use stage::Stage;
