//! Atomic folders: a dataset (or any folder of outputs) is written into a temporary sibling folder that is renamed
//! onto the target only when complete ([`StagingDir`]), so a failed or interrupted run never leaves a half-written
//! folder behind (and an old target is replaced only after the new one is complete). Used by `msnerf simulate` and
//! `msnerf import rig`.

use std::path::{Path, PathBuf};

/// Why a staging folder could not be made or committed; names the path.
#[derive(Debug, thiserror::Error)]
pub enum StagingError {
    #[error("{} already exists (pass --overwrite to replace it)", .0.display())]
    Exists(PathBuf),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StagingError + '_ {
    move |source| StagingError::Io { path: path.to_path_buf(), source }
}

/// A folder written next to the target and renamed onto it by [`StagingDir::commit`]; removed on drop.
pub struct StagingDir {
    pub path: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl StagingDir {
    /// Creates the staging folder for `target` (which must not exist unless `overwrite`).
    pub fn new(target: &Path, overwrite: bool) -> Result<StagingDir, StagingError> {
        if target.exists() && !overwrite {
            return Err(StagingError::Exists(target.to_path_buf()));
        }
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(io_err(&parent))?;
        let nanos =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        let path = parent.join(format!(".{name}.partial-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&path).map_err(io_err(&path))?;
        Ok(StagingDir { path, target: target.to_path_buf(), committed: false })
    }

    /// Moves the finished folder onto the target (replacing an old one only after the new one is complete).
    pub fn commit(mut self) -> Result<(), StagingError> {
        let old = if self.target.exists() {
            let o = self.path.with_extension("old");
            std::fs::rename(&self.target, &o).map_err(io_err(&self.target))?;
            Some(o)
        } else {
            None
        };
        std::fs::rename(&self.path, &self.target).map_err(io_err(&self.target))?;
        self.committed = true;
        if let Some(o) = old {
            std::fs::remove_dir_all(&o).map_err(io_err(&o))?;
        }
        Ok(())
    }
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}
