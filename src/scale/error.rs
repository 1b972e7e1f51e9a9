//! `ScaleError`: every problem of partitioning and block-wise training names the dataset, option, block or file.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ScaleError {
    #[error(transparent)]
    Data(#[from] crate::data::DataError),
    #[error("{}: {reason}", path.display())]
    Dataset { path: PathBuf, reason: String },
    #[error("option {key}: {reason}")]
    Option { key: String, reason: String },
    #[error("{}: {reason}", path.display())]
    Output { path: PathBuf, reason: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("block {block}: {reason}")]
    Block { block: String, reason: String },
}

impl ScaleError {
    pub fn option(key: &str, reason: impl Into<String>) -> ScaleError {
        ScaleError::Option { key: key.into(), reason: reason.into() }
    }
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ScaleError + '_ {
        move |source| ScaleError::Io { path: path.to_path_buf(), source }
    }
}
