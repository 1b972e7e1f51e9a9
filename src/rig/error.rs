//! `RigError`: every problem of a raw-rig import names the file, and the tag, option or capture concerned.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a readable TIFF: {reason}", path.display())]
    Tiff { path: PathBuf, reason: String },
    #[error("{}: missing metadata tag {tag} ({why})", path.display())]
    MissingTag { path: PathBuf, tag: String, why: String },
    #[error("{}: metadata tag {tag}: {reason}", path.display())]
    BadTag { path: PathBuf, tag: String, reason: String },
    #[error("{}: unknown camera vendor: {read}; msnerf needs {missing}", path.display())]
    UnknownVendor { path: PathBuf, read: String, missing: String },
    #[error("mixed cameras or firmware conventions in one folder: {a} ({}) and {b} ({})", a_path.display(), b_path.display())]
    Mixed { a: String, a_path: PathBuf, b: String, b_path: PathBuf },
    #[error("{}: calibration panel not found ({reason}); give its corners with --panel-corners x1,y1,x2,y2,x3,y3,x4,y4", path.display())]
    PanelNotFound { path: PathBuf, reason: String },
    #[error("{}: panel: {reason}", path.display())]
    Panel { path: PathBuf, reason: String },
    #[error("{}: a thermal band ({band}, {center_nm} nm): msnerf trains on the reflective bands, so it is left out", path.display())]
    Thermal { path: PathBuf, band: String, center_nm: f64 },
    #[error("option {key}: {reason}")]
    Option { key: String, reason: String },
    #[error("capture {capture}: {reason}")]
    Capture { capture: String, reason: String },
    #[error("{}: {reason}", path.display())]
    Output { path: PathBuf, reason: String },
}

impl RigError {
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> RigError + '_ {
        move |source| RigError::Io { path: path.to_path_buf(), source }
    }
    pub fn missing(path: &Path, tag: &str, why: &str) -> RigError {
        RigError::MissingTag { path: path.to_path_buf(), tag: tag.into(), why: why.into() }
    }
    pub fn bad(path: &Path, tag: &str, reason: impl Into<String>) -> RigError {
        RigError::BadTag { path: path.to_path_buf(), tag: tag.into(), reason: reason.into() }
    }
    pub fn option(key: &str, reason: impl Into<String>) -> RigError {
        RigError::Option { key: key.into(), reason: reason.into() }
    }
}
