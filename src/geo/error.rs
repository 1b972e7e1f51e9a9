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

/// Errors reading or using a ground control file: each names the file, and the line where there is one.
#[derive(Debug, thiserror::Error)]
pub enum GcpError {
    #[error("{}: {reason}", path.display())]
    File { path: std::path::PathBuf, reason: String },
    #[error("{}, line {line}: {reason}", path.display())]
    Line { path: std::path::PathBuf, line: usize, reason: String },
}
