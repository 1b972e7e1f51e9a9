//! `SimError`: every simulator failure names the scene file (or output path) and the key it concerns.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A scene file that does not parse or does not make sense; `key` is a path like `boxes[2].roof`.
    #[error("{file}: {}{reason}", if key.is_empty() { String::new() } else { format!("{key}: ") })]
    Scene { file: String, key: String, reason: String },
    /// A bad option (command-line flag or `SimOptions` field).
    #[error("option --{key}: {reason}")]
    Option { key: String, reason: String },
    /// Writing the dataset failed.
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// Writing an output file (the ground-truth cloud) failed; the error names the file.
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
}

impl From<crate::util::staging::StagingError> for SimError {
    fn from(e: crate::util::staging::StagingError) -> Self {
        match e {
            crate::util::staging::StagingError::Exists(_) => {
                SimError::Option { key: "out".into(), reason: e.to_string() }
            }
            crate::util::staging::StagingError::Io { path, source } => SimError::Io { path, source },
        }
    }
}

impl SimError {
    pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> SimError {
        let path = path.into();
        move |source| SimError::Io { path, source }
    }
}
