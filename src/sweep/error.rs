//! `SweepError`: every way a sweep can fail, naming the file, the grid key, the cell or the stage (the project's
//! `data/error.rs` convention). A failing cell is recorded in its folder and the others still run.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// Reading, writing or creating a file or folder failed, or a file's content is malformed.
    #[error("{}: {reason}", path.display())]
    File { path: PathBuf, reason: String },
    /// The grid's text is malformed or out of range; `reason` names the key.
    #[error("{reason}")]
    Grid { reason: String },
    /// One cell's configuration or data is wrong.
    #[error("cell {index} ({describe}): {reason}")]
    Cell { index: usize, describe: String, reason: String },
    /// A stage of a cell's run failed (evaluating, comparing the cloud).
    #[error("{what}: {reason}")]
    Stage { what: String, reason: String },
    /// Training, loading or exporting a cell's run failed.
    #[error("{what}: {err}")]
    Run { what: String, err: Box<crate::nerf::NerfError> },
    /// A plot could not be drawn or written.
    #[error("drawing a plot: {0}")]
    Plot(String),
}

impl SweepError {
    pub fn grid(reason: impl Into<String>) -> Self {
        SweepError::Grid { reason: reason.into() }
    }

    pub fn file(path: &std::path::Path, reason: impl std::fmt::Display) -> Self {
        SweepError::File { path: path.to_path_buf(), reason: reason.to_string() }
    }
}

impl From<crate::util::atomic::WriteError> for SweepError {
    fn from(e: crate::util::atomic::WriteError) -> Self {
        SweepError::File { path: e.path, reason: e.reason }
    }
}
