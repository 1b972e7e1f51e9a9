//! Dataset files (spec/dataset.md): multi-band TIFFs, depth TIFFs, `transforms.json`, `simulation.json`, `README.md`, all written into a temporary sibling folder that is renamed into place
//! only when complete ([`StagingDir`]), so a failed or interrupted run never leaves a half-written dataset.
//!
//! TIFFs are little-endian classic TIFF, uncompressed, chunky (B samples per pixel, PhotometricInterpretation
//! BlackIsZero, B − 1 unspecified ExtraSamples, as GDAL writes them), strips of about 64 KiB.

use std::path::{Path, PathBuf};

use super::error::SimError;

/// A folder written next to the target and renamed onto it by [`StagingDir::commit`]; removed on drop.
pub struct StagingDir {
    pub path: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl StagingDir {
    /// Creates the staging folder for `target` (which must not exist unless `overwrite`).
    pub fn new(target: &Path, overwrite: bool) -> Result<StagingDir, SimError> {
        if target.exists() && !overwrite {
            return Err(SimError::Option {
                key: "out".into(),
                reason: format!("{} already exists (pass --overwrite to replace it)", target.display()),
            });
        }
        let name = target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into());
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(SimError::io(&parent))?;
        let nanos =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        let path = parent.join(format!(".{name}.partial-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&path).map_err(SimError::io(&path))?;
        Ok(StagingDir { path, target: target.to_path_buf(), committed: false })
    }

    /// Moves the finished folder onto the target (replacing an old one only after the new one is complete).
    pub fn commit(mut self) -> Result<(), SimError> {
        let old = if self.target.exists() {
            let o = self.path.with_extension("old");
            std::fs::rename(&self.target, &o).map_err(SimError::io(&self.target))?;
            Some(o)
        } else {
            None
        };
        std::fs::rename(&self.path, &self.target).map_err(SimError::io(&self.target))?;
        self.committed = true;
        if let Some(o) = old {
            std::fs::remove_dir_all(&o).map_err(SimError::io(&o))?;
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

/// Sample data for [`write_tiff`].
pub enum TiffData<'a> {
    F32(&'a [f32]),
    U16(&'a [u16]),
}

/// Writes a chunky `samples`-per-pixel TIFF (row-major, samples interleaved).
pub fn write_tiff(path: &Path, width: u32, height: u32, samples: usize, data: TiffData) -> Result<(), SimError> {
    let bytes = tiff_bytes(width, height, samples, data);
    std::fs::write(path, bytes).map_err(SimError::io(path))
}

/// The TIFF file bytes (see the module doc).
pub fn tiff_bytes(width: u32, height: u32, samples: usize, data: TiffData) -> Vec<u8> {
    let (bits, fmt, payload): (u32, u32, Vec<u8>) = match data {
        TiffData::F32(v) => (32, 3, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        TiffData::U16(v) => (16, 1, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
    };
    let row_bytes = width as usize * samples * bits as usize / 8;
    let rows_per_strip = (65536 / row_bytes.max(1)).clamp(1, height as usize);
    let mut out: Vec<u8> = b"II*\0\0\0\0\0".to_vec();
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    for chunk in payload.chunks(row_bytes * rows_per_strip) {
        offsets.push(out.len() as u32);
        counts.push(chunk.len() as u32);
        out.extend_from_slice(chunk);
    }
    if out.len() % 2 == 1 {
        out.push(0);
    }
    // (tag, type 3 SHORT / 4 LONG, values), sorted by tag.
    let mut tags: Vec<(u16, u16, Vec<u32>)> = vec![
        (256, 4, vec![width]),
        (257, 4, vec![height]),
        (258, 3, vec![bits; samples]),
        (259, 3, vec![1]),
        (262, 3, vec![1]),
        (273, 4, offsets),
        (277, 3, vec![samples as u32]),
        (278, 4, vec![rows_per_strip as u32]),
        (279, 4, counts),
        (284, 3, vec![1]),
    ];
    if samples > 1 {
        tags.push((338, 3, vec![0; samples - 1]));
    }
    tags.push((339, 3, vec![fmt; samples]));
    let ifd = out.len();
    out[4..8].copy_from_slice(&(ifd as u32).to_le_bytes());
    let mut extra_at = ifd + 2 + tags.len() * 12 + 4;
    let mut ifd_bytes = (tags.len() as u16).to_le_bytes().to_vec();
    let mut extra = Vec::new();
    for (tag, ty, vals) in &tags {
        let mut data = Vec::new();
        for v in vals {
            if *ty == 3 {
                data.extend_from_slice(&(*v as u16).to_le_bytes());
            } else {
                data.extend_from_slice(&v.to_le_bytes());
            }
        }
        ifd_bytes.extend_from_slice(&tag.to_le_bytes());
        ifd_bytes.extend_from_slice(&ty.to_le_bytes());
        ifd_bytes.extend_from_slice(&(vals.len() as u32).to_le_bytes());
        if data.len() <= 4 {
            data.resize(4, 0);
            ifd_bytes.extend_from_slice(&data);
        } else {
            ifd_bytes.extend_from_slice(&(extra_at as u32).to_le_bytes());
            extra_at += data.len();
            extra.extend_from_slice(&data);
        }
    }
    ifd_bytes.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&ifd_bytes);
    out.extend_from_slice(&extra);
    out
}

/// Writes pretty JSON.
pub fn write_json(path: &Path, v: &serde_json::Value) -> Result<(), SimError> {
    let s = serde_json::to_string_pretty(v).expect("JSON values serialise");
    std::fs::write(path, s + "\n").map_err(SimError::io(path))
}
