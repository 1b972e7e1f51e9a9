//! `NerfError`: what training, loading a run, rendering and exporting can fail with, naming the file, key, frame or
//! step (the project's `data/error.rs` convention; kajiya's `kajiya-backend/src/error.rs` for the shape). Errors of
//! the layers below (dataset, profile, parameters, GPU, outputs) are kept as they are, with what was being done.

use crate::data::DataError;
use crate::gpu::GpuError;
use crate::nn::params::ParamError;
use crate::output::OutputError;
use std::path::{Path, PathBuf};

use super::config_error::ConfigError;

#[derive(Debug, thiserror::Error)]
pub enum NerfError {
    /// The dataset (file, key or frame named by [`DataError`]).
    #[error(transparent)]
    Data(#[from] DataError),
    /// The model profile (file and key named by [`ConfigError`]).
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Parameters, checkpoints and their files.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// Writing an output.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// GPU work failed while doing `during` ("step 12", "rendering frame 3").
    #[error("{during}: {err}")]
    Gpu { during: String, err: GpuError },
    /// A file or folder could not be read, written or created.
    #[error("{}: {reason}", path.display())]
    File { path: PathBuf, reason: String },
    /// A file's content is wrong at `key` (a run's `dataset.json`, a camera path, depth targets).
    #[error("{}: {key}: {reason}", path.display())]
    Key { path: PathBuf, key: String, reason: String },
    /// An option (command-line flag or setting) out of range, or a request the data cannot serve.
    #[error("{what}: {reason}")]
    Invalid { what: String, reason: String },
    /// The NaN guard stopped training at `step`: `buffer` held a non-finite value.
    #[error(
        "step {step}: {count} steps in a row produced NaN/Inf (first in: {buffer}); stopping. The last good \
         checkpoint is in {}",
        checkpoints.display()
    )]
    NonFinite { step: u64, buffer: String, count: u32, checkpoints: PathBuf },
    /// Every step of a run (fewer than the guard's limit in a row) produced NaN/Inf: nothing was trained.
    #[error(
        "every one of this session's {steps} steps produced NaN/Inf (first in: {buffer}) and was skipped: \
         nothing was trained; check the dataset's pixel values and intrinsics"
    )]
    NothingTrained { steps: u64, buffer: String },
}

pub type NerfResult<T> = Result<T, NerfError>;

impl NerfError {
    /// GPU work failed while doing `during`.
    pub fn gpu(during: impl Into<String>) -> impl FnOnce(GpuError) -> Self {
        let during = during.into();
        move |err| NerfError::Gpu { during, err }
    }

    /// A file could not be read, written or created.
    pub fn file(path: &Path, reason: impl std::fmt::Display) -> Self {
        NerfError::File { path: path.to_path_buf(), reason: reason.to_string() }
    }

    /// A file's content is wrong at `key`.
    pub fn key(path: &Path, key: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        NerfError::Key { path: path.to_path_buf(), key: key.into(), reason: reason.to_string() }
    }

    /// An option or request out of range; `what` names it.
    pub fn invalid(what: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        NerfError::Invalid { what: what.into(), reason: reason.to_string() }
    }
}
