//! Errors of the CRS layer: each names the CRS text or the EPSG code that failed.

#[derive(Debug, thiserror::Error)]
pub enum CrsError {
    #[error("crs {given:?}: {reason}")]
    Invalid { given: String, reason: String },
    #[error("crs {crs}: {reason}")]
    Projection { crs: String, reason: String },
}

impl CrsError {
    pub fn invalid(given: &str, reason: impl Into<String>) -> Self {
        CrsError::Invalid { given: given.chars().take(120).collect(), reason: reason.into() }
    }
}
