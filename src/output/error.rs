//! `OutputError`: every way an output can fail, naming the file or the parameter concerned.

use std::path::{Path, PathBuf};

/// A failed output operation. I/O errors carry the path; bad arguments carry the parameter name.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Creating, writing or renaming a file failed.
    #[error("{}: cannot write: {reason}", path.display())]
    Write { path: PathBuf, reason: String },
    /// Reading or decoding a file failed.
    #[error("{}: cannot read: {reason}", path.display())]
    Read { path: PathBuf, reason: String },
    /// An argument has the wrong shape or value; `what` names it.
    #[error("{what}: {reason}")]
    Invalid { what: String, reason: String },
    /// A computation needs a band near a wavelength that the image does not have.
    #[error("{what}: needs a band within {tolerance_nm} nm of {wavelength_nm} nm; bands present: {available}")]
    MissingBand { what: String, wavelength_nm: f64, tolerance_nm: f64, available: String },
}

impl OutputError {
    pub fn write(path: &Path, reason: impl std::fmt::Display) -> Self {
        OutputError::Write { path: path.to_path_buf(), reason: reason.to_string() }
    }
    pub fn read(path: &Path, reason: impl std::fmt::Display) -> Self {
        OutputError::Read { path: path.to_path_buf(), reason: reason.to_string() }
    }
    pub fn invalid(what: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        OutputError::Invalid { what: what.into(), reason: reason.to_string() }
    }
}

impl From<crate::util::atomic::WriteError> for OutputError {
    fn from(e: crate::util::atomic::WriteError) -> Self {
        OutputError::Write { path: e.path, reason: e.reason }
    }
}
