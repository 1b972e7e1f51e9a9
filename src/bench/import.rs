//! `msnerf bench import DIR`: how fast raw rig captures become a dataset on this machine. Times each stage of
//! one capture on one thread (read + radiance, per-capture registration of every band, resampling + crop +
//! TIFF), then whole imports of the folder with every core, per-capture registration and shared rig warps.
//!
//! `--replicate N` makes an N-capture flight from the folder's captures by giving copies of each file new
//! capture ids (the XMP `CaptureId` bytes rewritten in place, same length), so a folder with one real capture
//! can stand for a flight.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::rig::capture::{list_tiffs, scan_files};
use crate::rig::frame::{estimate_warps, load, valid_rect, write_frame};
use crate::rig::{import_rig, ImportOptions, Registration, RigError, Units};

/// The numbers `bench import` prints.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ImportBench {
    pub captures: usize,
    pub bands: usize,
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    /// One capture, one thread: seconds per stage.
    pub load_radiance_s: f64,
    pub register_capture_s: f64,
    pub resample_write_s: f64,
    /// Whole imports with every core: seconds, and band images per second.
    pub import_capture_s: f64,
    pub import_rig_s: f64,
    pub images_per_s_capture: f64,
    pub images_per_s_rig: f64,
}

impl ImportBench {
    pub fn table(&self) -> String {
        format!(
            "import of {} captures x {} bands of {}x{} on {} threads\n\
             one capture, one thread: read + radiance {:.2} s, registration {:.2} s, resample + write {:.2} s\n\
             whole import, --register capture: {:.1} s ({:.1} images/s)\n\
             whole import, --register rig:     {:.1} s ({:.1} images/s)\n",
            self.captures,
            self.bands,
            self.width,
            self.height,
            self.threads,
            self.load_radiance_s,
            self.register_capture_s,
            self.resample_write_s,
            self.import_capture_s,
            self.images_per_s_capture,
            self.import_rig_s,
            self.images_per_s_rig,
        )
    }
}

/// Copies the flight's TIFFs `n` times into `dst`, giving each copy a new capture id of the same length.
fn replicate(src: &Path, dst: &Path, n: usize) -> Result<(), RigError> {
    let scan = scan_files(&list_tiffs(src)?)?;
    std::fs::create_dir_all(dst).map_err(RigError::io(dst))?;
    for k in 0..n {
        for cap in &scan.captures {
            let id = cap.key.as_bytes();
            let tag = format!("{k:04}");
            if id.len() < tag.len() {
                return Err(RigError::option("--replicate", format!("capture id {:?} too short to rewrite", cap.key)));
            }
            let mut new_id = id.to_vec();
            let at = new_id.len() - tag.len();
            new_id[at..].copy_from_slice(tag.as_bytes());
            for b in &cap.bands {
                let p = &b.meta.path;
                let mut bytes = std::fs::read(p).map_err(RigError::io(p))?;
                let mut i = 0;
                while let Some(pos) = bytes[i..].windows(id.len()).position(|w| w == id) {
                    bytes[i + pos..i + pos + id.len()].copy_from_slice(&new_id);
                    i += pos + id.len();
                }
                let name =
                    format!("r{k:04}_{}", p.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default());
                let out = dst.join(name);
                std::fs::write(&out, bytes).map_err(RigError::io(&out))?;
            }
        }
    }
    Ok(())
}

/// Runs the benchmark on `dir` (radiance units: no panel needed), `replicate` copies of its captures.
pub fn run(dir: &Path, replicate_n: usize, threads: usize) -> Result<ImportBench, RigError> {
    let work = std::env::temp_dir().join(format!("msnerf-bench-import-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    let flight: PathBuf = if replicate_n > 1 {
        let f = work.join("flight");
        replicate(dir, &f, replicate_n)?;
        f
    } else {
        dir.to_path_buf()
    };
    let result = (|| {
        let scan = scan_files(&list_tiffs(&flight)?)?;
        let cap = scan.captures.first().ok_or_else(|| RigError::option("DIR", "no complete capture"))?;
        let ref_idx = (0..cap.bands.len())
            .min_by(|&a, &b| (cap.bands[a].center_nm - 560.0).abs().total_cmp(&(cap.bands[b].center_nm - 560.0).abs()))
            .unwrap_or(0);
        let t = Instant::now();
        let l = load(cap, None)?;
        let load_radiance_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let regs = estimate_warps(cap, &l, ref_idx, true, true);
        let register_capture_s = t.elapsed().as_secs_f64();
        let rect =
            valid_rect(cap, &regs, ref_idx, true).ok_or_else(|| RigError::option("DIR", "bands share no area"))?;
        let scratch = work.join("scratch");
        std::fs::create_dir_all(scratch.join("images")).map_err(RigError::io(&scratch))?;
        let t = Instant::now();
        write_frame(cap, &l, regs, ref_idx, true, rect, &scratch)?;
        let resample_write_s = t.elapsed().as_secs_f64();
        let whole = |registration: Registration, name: &str| -> Result<f64, RigError> {
            let opts = ImportOptions {
                units: Units::Radiance,
                registration,
                register_sample: 8,
                overwrite: true,
                threads,
                ..ImportOptions::new(flight.clone(), work.join(name))
            };
            Ok(import_rig(&opts)?.seconds)
        };
        let import_capture_s = whole(Registration::Capture, "capture")?;
        let import_rig_s = whole(Registration::Rig, "rig")?;
        let images = (scan.captures.len() * cap.bands.len()) as f64;
        Ok(ImportBench {
            captures: scan.captures.len(),
            bands: cap.bands.len(),
            width: cap.bands[0].meta.width,
            height: cap.bands[0].meta.height,
            threads,
            load_radiance_s,
            register_capture_s,
            resample_write_s,
            import_capture_s,
            import_rig_s,
            images_per_s_capture: images / import_capture_s,
            images_per_s_rig: images / import_rig_s,
        })
    })();
    let _ = std::fs::remove_dir_all(&work);
    result
}
