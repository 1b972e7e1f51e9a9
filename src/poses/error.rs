//! `PoseError`: every problem of a pose import names the file, and the line, record or image concerned.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: {at}: {reason}", path.display())]
    Parse { path: PathBuf, at: String, reason: String },
    #[error("{}: {reason}", path.display())]
    Dataset { path: PathBuf, reason: String },
    #[error("option {key}: {reason}")]
    Option { key: String, reason: String },
}

impl PoseError {
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> PoseError + '_ {
        move |source| PoseError::Io { path: path.to_path_buf(), source }
    }
    pub fn parse(path: &Path, at: impl Into<String>, reason: impl Into<String>) -> PoseError {
        PoseError::Parse { path: path.to_path_buf(), at: at.into(), reason: reason.into() }
    }
}
