//! `ProcessError`: a stage of `msnerf process` that could not run or finish, naming the stage and, through the
//! layer's own error, the file, tag, key or option concerned.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("option {key}: {reason}")]
    Option { key: String, reason: String },
    #[error("stage record {}: {reason} (remove it to run the stage again)", path.display())]
    Record { path: PathBuf, reason: String },
    #[error(
        "stage `{stage}`: its output {file} was changed after the stage wrote it ({what}); rerun with --redo {stage} \
         to make it again, or restore the file"
    )]
    Edited { stage: String, file: String, what: String },
    #[error("stage `{stage}`: {reason}")]
    Stage { stage: String, reason: String },
    #[error("{}: {reason}", path.display())]
    Output { path: PathBuf, reason: String },
}

impl ProcessError {
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
        move |source| ProcessError::Io { path: path.to_path_buf(), source }
    }
    /// A stage's failure, from any layer's error.
    pub fn stage(stage: super::Stage) -> impl Fn(&dyn std::fmt::Display) -> ProcessError + Copy {
        move |e| ProcessError::Stage { stage: stage.name().into(), reason: e.to_string() }
    }
}
