//! The stages of `msnerf process` and their records.
//!
//! Each stage writes its outputs, then `PROJECT/stages/<stage>.json`: what went in (a fingerprint of its options and
//! of the outputs of the stages it reads), what came out (every file it owns with its size, modification time and,
//! below [`HASH_LIMIT`] bytes, its SHA-256), its time and peak memory, and a summary for the report. A rerun skips a
//! stage whose record matches its inputs and whose outputs are as it left them; a record whose inputs changed reruns
//! the stage and every stage after it; an output changed since (edited by hand, half-copied) stops the run naming
//! the file. A stage that crashed left no record, so it runs again, from its checkpoint where it has one (training).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::error::ProcessError;

/// The stages, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stage {
    /// Raw rig files -> calibrated, registered dataset (`msnerf import rig`).
    Import,
    /// Poses and sparse points: COLMAP (`msnerf sfm`), or `--poses` from COLMAP, OpenSfM, ODM or Metashape.
    Poses,
    /// `msnerf dataset check`: stops the run on a problem.
    Check,
    /// `msnerf train` with the hardware's profile and depth supervision from the sparse points.
    Train,
    /// Held-out views: PSNR and SSIM per band (`msnerf eval`).
    Eval,
    /// The multispectral point cloud (LAS).
    Cloud,
    /// DSM, true orthomosaic and vegetation-index rasters on one grid.
    Survey,
    /// DTM (SMRF ground filter of the DSM), canopy height model and trees, on the DSM's grid.
    Terrain,
    /// The processing report (HTML).
    Report,
}

impl Stage {
    pub const ALL: [Stage; 9] = [
        Stage::Import,
        Stage::Poses,
        Stage::Check,
        Stage::Train,
        Stage::Eval,
        Stage::Cloud,
        Stage::Survey,
        Stage::Terrain,
        Stage::Report,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Import => "import",
            Stage::Poses => "poses",
            Stage::Check => "check",
            Stage::Train => "train",
            Stage::Eval => "eval",
            Stage::Cloud => "cloud",
            Stage::Survey => "survey",
            Stage::Terrain => "terrain",
            Stage::Report => "report",
        }
    }

    pub fn index(self) -> usize {
        Stage::ALL.iter().position(|s| *s == self).expect("every stage is listed")
    }
}

/// Files larger than this are fingerprinted by size and modification time only (training images, checkpoints).
pub const HASH_LIMIT: u64 = 64 << 20;

/// One output file as the stage left it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileStamp {
    /// Relative to the project folder.
    pub path: String,
    pub size: u64,
    pub modified_ns: u128,
    /// SHA-256 (hex) of files below [`HASH_LIMIT`].
    pub sha256: Option<String>,
}

/// What a stage did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageRecord {
    pub stage: Stage,
    pub msnerf: String,
    /// SHA-256 of the stage's options and of its upstream stages' output fingerprints.
    pub inputs: String,
    pub outputs: Vec<FileStamp>,
    /// SHA-256 of `outputs`: what the next stages' inputs include.
    pub outputs_fingerprint: String,
    /// UTC, seconds since 1970.
    pub finished_unix_s: u64,
    pub seconds: f64,
    pub peak_host_bytes: Option<u64>,
    pub peak_gpu_bytes: Option<u64>,
    /// What the report shows of the stage.
    pub summary: serde_json::Value,
}

/// SHA-256 (hex) of bytes.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

fn file_sha256(path: &Path) -> Result<String, ProcessError> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(ProcessError::io(path))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(ProcessError::io(path))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Stamps of `files` (paths relative to `project`; folders are walked, sorted).
pub fn stamp(project: &Path, files: &[PathBuf]) -> Result<Vec<FileStamp>, ProcessError> {
    let mut all = Vec::new();
    for f in files {
        let p = project.join(f);
        if p.is_dir() {
            let mut stack = vec![p.clone()];
            while let Some(d) = stack.pop() {
                for e in std::fs::read_dir(&d).map_err(ProcessError::io(&d))? {
                    let q = e.map_err(ProcessError::io(&d))?.path();
                    if q.is_dir() {
                        stack.push(q);
                    } else {
                        all.push(q);
                    }
                }
            }
        } else {
            all.push(p);
        }
    }
    all.sort();
    all.iter()
        .map(|p| {
            let m = std::fs::metadata(p).map_err(ProcessError::io(p))?;
            let modified_ns = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos());
            let sha256 = if m.len() <= HASH_LIMIT { Some(file_sha256(p)?) } else { None };
            let rel = p.strip_prefix(project).unwrap_or(p).to_string_lossy().into_owned();
            Ok(FileStamp { path: rel, size: m.len(), modified_ns, sha256 })
        })
        .collect()
}

/// The fingerprint of a list of stamps.
pub fn stamps_fingerprint(stamps: &[FileStamp]) -> String {
    sha256_hex(serde_json::to_string(stamps).expect("stamps serialise").as_bytes())
}

/// The folder of the records.
pub fn records_dir(project: &Path) -> PathBuf {
    project.join("stages")
}

/// Reads a stage's record, if it has one; a record that does not parse is an error naming it.
pub fn read_record(project: &Path, stage: Stage) -> Result<Option<StageRecord>, ProcessError> {
    let p = records_dir(project).join(format!("{}.json", stage.name()));
    if !p.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&p).map_err(ProcessError::io(&p))?;
    serde_json::from_str(&text).map(Some).map_err(|e| ProcessError::Record { path: p, reason: e.to_string() })
}

/// Writes a stage's record (atomically).
pub fn write_record(project: &Path, r: &StageRecord) -> Result<(), ProcessError> {
    let dir = records_dir(project);
    std::fs::create_dir_all(&dir).map_err(ProcessError::io(&dir))?;
    let p = dir.join(format!("{}.json", r.stage.name()));
    crate::util::atomic::write_bytes(&p, serde_json::to_string_pretty(r).expect("records serialise").as_bytes())
        .map_err(|e| ProcessError::Output { path: p.clone(), reason: e.to_string() })
}

/// Removes a stage's record (its outputs are about to be replaced).
pub fn remove_record(project: &Path, stage: Stage) -> Result<(), ProcessError> {
    let p = records_dir(project).join(format!("{}.json", stage.name()));
    match std::fs::remove_file(&p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(ProcessError::io(&p)(e)),
    }
}

/// How a stage's record compares with what it would be now.
#[derive(Debug, Clone, PartialEq)]
pub enum Freshness {
    /// No record: the stage runs.
    Missing,
    /// Its inputs changed: it runs again (and every later stage).
    Stale,
    /// Its outputs are as it left them and its inputs unchanged: skipped.
    Current,
    /// An output differs from what the stage wrote: `(file, what differs)`.
    Edited(String, String),
}

/// Compares a record with the current inputs fingerprint and the files on disk.
pub fn freshness(project: &Path, record: Option<&StageRecord>, inputs: &str) -> Result<Freshness, ProcessError> {
    let Some(r) = record else { return Ok(Freshness::Missing) };
    if r.inputs != inputs {
        return Ok(Freshness::Stale);
    }
    for s in &r.outputs {
        let p = project.join(&s.path);
        let Ok(m) = std::fs::metadata(&p) else {
            return Ok(Freshness::Edited(s.path.clone(), "it is missing".into()));
        };
        if m.len() != s.size {
            return Ok(Freshness::Edited(
                s.path.clone(),
                format!("{} bytes where the stage wrote {}", m.len(), s.size),
            ));
        }
        if let Some(h) = &s.sha256 {
            if &file_sha256(&p)? != h {
                return Ok(Freshness::Edited(s.path.clone(), "its content differs from what the stage wrote".into()));
            }
        } else {
            let modified = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos());
            if modified != s.modified_ns {
                return Ok(Freshness::Edited(s.path.clone(), "it was modified after the stage wrote it".into()));
            }
        }
    }
    Ok(Freshness::Current)
}
