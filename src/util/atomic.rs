//! Atomic file writes: write a temporary file in the destination folder, then rename it over the target, so a
//! reader never sees a half-written output and a failed write leaves any previous file in place.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A failed atomic write, naming the target file.
#[derive(Debug, thiserror::Error)]
#[error("{}: {reason}", path.display())]
pub struct WriteError {
    pub path: PathBuf,
    pub reason: String,
}

impl WriteError {
    fn new(path: &Path, reason: impl std::fmt::Display) -> Self {
        WriteError { path: path.to_path_buf(), reason: reason.to_string() }
    }
}

pub type Result<T> = std::result::Result<T, WriteError>;

/// A temporary file that becomes `target` on [`AtomicFile::commit`]; dropped uncommitted, it is removed.
pub struct AtomicFile {
    tmp: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl AtomicFile {
    /// Creates `.<name>.tmp<pid>` next to `target` and opens it for writing.
    pub fn create(target: &Path) -> Result<(AtomicFile, File)> {
        let name = target
            .file_name()
            .ok_or_else(|| WriteError::new(target, "not a file path"))?
            .to_string_lossy()
            .into_owned();
        let dir = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
        let file = File::create(&tmp).map_err(|e| WriteError::new(target, e))?;
        Ok((AtomicFile { tmp, target: target.to_path_buf(), committed: false }, file))
    }

    /// Renames the temporary file onto the target.
    pub fn commit(mut self) -> Result<()> {
        std::fs::rename(&self.tmp, &self.target).map_err(|e| WriteError::new(&self.target, e))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// Streams into `path` atomically through a buffered writer.
pub fn write_with(path: &Path, f: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>) -> Result<()> {
    let (atomic, file) = AtomicFile::create(path)?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    f(&mut w).map_err(|e| WriteError::new(path, e))?;
    let file = w.into_inner().map_err(|e| WriteError::new(path, e.error()))?;
    file.sync_all().map_err(|e| WriteError::new(path, e))?;
    drop(file);
    atomic.commit()
}

/// Refuses to write `output` over one of the command's inputs (`(flag, path)` pairs): an atomic write would
/// replace the input itself. Paths are compared after resolving links and `..`; an output that does not exist yet
/// is no input.
pub fn check_not_an_input(output: &Path, inputs: &[(&str, &Path)]) -> std::result::Result<(), WriteError> {
    let Ok(out) = output.canonicalize() else { return Ok(()) };
    for (flag, input) in inputs {
        if input.canonicalize().is_ok_and(|i| i == out) {
            return Err(WriteError::new(output, format!("is the {flag} input: choose another output path")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod input_tests {
    use super::check_not_an_input;

    #[test]
    fn an_output_that_is_an_input_is_refused_by_flag() {
        let dir = std::env::temp_dir().join(format!("msnerf-atomic-inputs-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let input = dir.join("ref.ply");
        std::fs::write(&input, b"x").unwrap();
        let same = dir.join("sub/../ref.ply");
        let e = check_not_an_input(&same, &[("--pred", &dir.join("pred.ply")), ("--ref", &input)]).unwrap_err();
        assert!(e.to_string().contains("is the --ref input"), "{e}");
        check_not_an_input(&dir.join("report.json"), &[("--ref", &input)]).expect("a new file is no input");
        std::fs::write(dir.join("other.json"), b"{}").unwrap();
        check_not_an_input(&dir.join("other.json"), &[("--ref", &input)]).expect("another existing file");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
