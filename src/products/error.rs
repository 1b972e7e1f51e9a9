//! `ProductError`: a product that could not be made, naming the option or the file.

#[derive(Debug, thiserror::Error)]
pub enum ProductError {
    /// A bad option; `key` is the flag or option name.
    #[error("{key}: {reason}")]
    Option { key: String, reason: String },
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    #[error(transparent)]
    Nerf(#[from] crate::nerf::NerfError),
}

impl ProductError {
    pub fn option(key: &str, reason: impl Into<String>) -> ProductError {
        ProductError::Option { key: key.into(), reason: reason.into() }
    }
}
