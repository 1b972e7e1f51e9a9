//! `ProductError`: a product that could not be made, naming the option or the file.

#[derive(Debug, thiserror::Error)]
pub enum ProductError {
    /// A bad option; `key` is the flag or option name.
    #[error("{key}: {reason}")]
    Option { key: String, reason: String },
    /// An input file that cannot serve (empty, on another grid, without heights); `path` names it.
    #[error("{}: {reason}", path.display())]
    Input { path: std::path::PathBuf, reason: String },
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    #[error(transparent)]
    Survey(#[from] crate::nerf::survey::SurveyError),
    #[error(transparent)]
    Nerf(#[from] crate::nerf::NerfError),
}

impl ProductError {
    pub fn option(key: &str, reason: impl Into<String>) -> ProductError {
        ProductError::Option { key: key.into(), reason: reason.into() }
    }

    pub fn input(path: &std::path::Path, reason: impl Into<String>) -> ProductError {
        ProductError::Input { path: path.to_path_buf(), reason: reason.into() }
    }
}
