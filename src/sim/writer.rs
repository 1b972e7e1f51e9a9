//! The simulator's dataset files (spec/dataset.md): multi-band and depth TIFFs ([`crate::util::tiff`]),
//! `transforms.json`, `simulation.json`, `README.md`, all written into a [`StagingDir`] that is renamed into place
//! only when complete.

use std::path::Path;

use super::error::SimError;
pub use crate::util::staging::StagingDir;
pub use crate::util::tiff::{tiff_bytes, TiffData};

/// Writes a chunky `samples`-per-pixel TIFF (row-major, samples interleaved); errors name the file.
pub fn write_tiff(path: &Path, width: u32, height: u32, samples: usize, data: TiffData) -> Result<(), SimError> {
    crate::util::tiff::write_tiff(path, width, height, samples, data).map_err(SimError::io(path))
}

/// Writes pretty JSON.
pub fn write_json(path: &Path, v: &serde_json::Value) -> Result<(), SimError> {
    let s = serde_json::to_string_pretty(v).expect("JSON values serialise");
    std::fs::write(path, s + "\n").map_err(SimError::io(path))
}
