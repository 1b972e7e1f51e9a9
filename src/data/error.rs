//! `DataError`: every way a dataset can be rejected, each naming the file and the key or frame it concerns.
//!
//! Errors are values, never panics: the loader collects them (see [`DataError::Many`]) so that
//! `dataset check` can list every problem at once instead of stopping at the first.

use std::fmt;
use std::path::{Path, PathBuf};

/// Which frame of `transforms.json` an error concerns (index in file order and its image name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameRef {
    /// Index of the frame in the `frames` list as written in the file.
    pub index: usize,
    /// `file_path` (or the first of `band_files`) of that frame, if it had one.
    pub name: String,
}

impl fmt::Display for FrameRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.name.is_empty() {
            write!(f, "frame {}", self.index)
        } else {
            write!(f, "frame {} ({})", self.index, self.name)
        }
    }
}

fn fr(frame: &Option<FrameRef>) -> String {
    match frame {
        Some(fr) => format!("{fr}: "),
        None => String::new(),
    }
}

/// A problem with a dataset. Every variant carries the file (`path`) it concerns and, where it
/// applies, the `transforms.json` key and the frame.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A file named by `key` does not exist or cannot be opened.
    #[error("{}: {}key `{key}`: file missing or unreadable: {reason}", path.display(), fr(frame))]
    MissingFile { path: PathBuf, key: String, frame: Option<FrameRef>, reason: String },
    /// A file exists but cannot be decoded (corrupt, truncated, unsupported variant).
    #[error("{}: {}cannot decode: {reason}", path.display(), fr(frame))]
    Decode { path: PathBuf, frame: Option<FrameRef>, reason: String },
    /// `transforms.json` is not valid JSON.
    #[error("{}: invalid JSON: {reason}", path.display())]
    Json { path: PathBuf, reason: String },
    /// A required key is absent.
    #[error("{}: {}missing key `{key}`", path.display(), fr(frame))]
    MissingKey { path: PathBuf, key: String, frame: Option<FrameRef> },
    /// A key holds a value of the wrong type or outside its domain.
    #[error("{}: {}key `{key}`: {reason}", path.display(), fr(frame))]
    InvalidValue { path: PathBuf, key: String, frame: Option<FrameRef>, reason: String },
    /// `fl_x` / `fl_y` is zero or negative.
    #[error("{}: {}key `{key}`: focal length must be positive, got {value}", path.display(), fr(frame))]
    NonPositiveFocal { path: PathBuf, key: String, frame: Option<FrameRef>, value: f64 },
    /// The rotation part of `transform_matrix` is not orthonormal (max |RᵀR − I| or det ≠ +1).
    #[error("{}: {}key `transform_matrix`: rotation part is not orthonormal (max deviation {deviation:.3e})", path.display(), fr(frame))]
    NotOrthonormal { path: PathBuf, frame: Option<FrameRef>, deviation: f64 },
    /// An image holds a different number of bands than the header declares.
    #[error("{}: {}band count {found} does not match the {expected} bands of the header (key `{key}`)", path.display(), fr(frame))]
    BandCount { path: PathBuf, key: String, frame: Option<FrameRef>, expected: usize, found: usize },
    /// An image's size differs from `w` x `h` of the header.
    #[error("{}: {}image size {}x{} does not match the header's {}x{} (key `{key}`)", path.display(), fr(frame), found.0, found.1, expected.0, expected.1)]
    ImageSize { path: PathBuf, key: String, frame: Option<FrameRef>, expected: (u32, u32), found: (u32, u32) },
    /// Float pixels that are NaN or infinite (pass `mask_non_finite` to mask them out instead).
    #[error("{}: {}{count} NaN/Inf pixel values", path.display(), fr(frame))]
    NonFinite { path: PathBuf, frame: Option<FrameRef>, count: u64 },
    /// Finite pixel values beyond ±[`super::raster::MAX_MODEL_VALUE`] (a nodata marker, a unit mistake).
    #[error(
        "{}: {}{count} pixel values beyond ±1e6 (up to {extreme:e}) outside any mask: a nodata value or a unit \
         mistake; calibrated reflectance lies near [0, 1]. Mask such pixels out (`mask_path`: 0 where nodata)",
        path.display(),
        fr(frame)
    )]
    OutOfRange { path: PathBuf, frame: Option<FrameRef>, count: u64, extreme: f64 },
    /// No frame ends up in the train split.
    #[error("{}: key `{key}`: the train split is empty", path.display())]
    EmptyTrainSplit { path: PathBuf, key: String },
    /// Two frames name the same image file.
    #[error("{}: {}key `{key}`: duplicate file name `{name}`", path.display(), fr(frame))]
    DuplicateFileName { path: PathBuf, key: String, frame: Option<FrameRef>, name: String },
    /// A camera centre far outside the others (a GPS glitch or a typo); `drop_outliers` excludes it instead.
    #[error("{}: {}key `transform_matrix`: camera centre {distance:.6e} world units from the median centre, {:.0}x the cameras' median distance to it ({spread:.3e}): a GPS glitch or a typo? Fix the pose, or pass --drop-outliers to leave the frame out", path.display(), fr(frame), distance / spread)]
    OutlierCamera { path: PathBuf, frame: Option<FrameRef>, distance: f64, spread: f64 },
    /// Several problems at once, in the order they were found.
    #[error("{} problems:\n{}", .0.len(), .0.iter().map(|e| format!("  - {e}")).collect::<Vec<_>>().join("\n"))]
    Many(Vec<DataError>),
}

impl DataError {
    /// The file this error concerns (the first one for [`DataError::Many`]).
    pub fn path(&self) -> Option<&Path> {
        match self {
            DataError::MissingFile { path, .. }
            | DataError::Decode { path, .. }
            | DataError::Json { path, .. }
            | DataError::MissingKey { path, .. }
            | DataError::InvalidValue { path, .. }
            | DataError::NonPositiveFocal { path, .. }
            | DataError::NotOrthonormal { path, .. }
            | DataError::OutlierCamera { path, .. }
            | DataError::BandCount { path, .. }
            | DataError::ImageSize { path, .. }
            | DataError::NonFinite { path, .. }
            | DataError::OutOfRange { path, .. }
            | DataError::EmptyTrainSplit { path, .. }
            | DataError::DuplicateFileName { path, .. } => Some(path),
            DataError::Many(v) => v.first().and_then(|e| e.path()),
        }
    }

    /// Flattens [`DataError::Many`] into its members.
    pub fn flatten(self) -> Vec<DataError> {
        match self {
            DataError::Many(v) => v.into_iter().flat_map(|e| e.flatten()).collect(),
            e => vec![e],
        }
    }

    /// One error from a list: the error itself when there is one, [`DataError::Many`] otherwise.
    pub fn from_list(mut v: Vec<DataError>) -> Option<DataError> {
        match v.len() {
            0 => None,
            1 => v.pop(),
            _ => Some(DataError::Many(v)),
        }
    }

    /// Attaches a frame to an error that has none yet.
    pub fn with_frame(mut self, f: &FrameRef) -> DataError {
        match &mut self {
            DataError::MissingFile { frame, .. }
            | DataError::Decode { frame, .. }
            | DataError::MissingKey { frame, .. }
            | DataError::InvalidValue { frame, .. }
            | DataError::NonPositiveFocal { frame, .. }
            | DataError::NotOrthonormal { frame, .. }
            | DataError::OutlierCamera { frame, .. }
            | DataError::BandCount { frame, .. }
            | DataError::ImageSize { frame, .. }
            | DataError::NonFinite { frame, .. }
            | DataError::OutOfRange { frame, .. }
            | DataError::DuplicateFileName { frame, .. } => {
                if frame.is_none() {
                    *frame = Some(f.clone());
                }
            }
            DataError::Many(v) => {
                let taken = std::mem::take(v);
                *v = taken.into_iter().map(|e| e.with_frame(f)).collect();
            }
            DataError::Json { .. } | DataError::EmptyTrainSplit { .. } => {}
        }
        self
    }
}
