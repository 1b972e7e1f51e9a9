//! Finds the captures in a flight folder: every TIFF's tags are read (headers only), interpreted by vendor
//! ([`super::calib`]) and grouped by the capture identifier the XMP carries (MicaSense `CaptureId`, DJI
//! `CaptureUUID`, Pix4D `CaptureUUID`, else the EXIF time), never by file-name suffix. Bands are ordered by
//! centre wavelength. Files that cannot be used and captures missing a band are listed with the reason.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::calib::{interpret, BandFile};
use super::error::RigError;
use super::meta::read_meta;

/// One trigger of the rig: a file per band, in wavelength order.
#[derive(Debug, Clone)]
pub struct Capture {
    pub key: String,
    pub bands: Vec<BandFile>,
}

impl Capture {
    /// A file-name-safe name for the capture (the first band's file stem without its band suffix when it has one).
    pub fn name(&self) -> String {
        let stem = self.bands[0].meta.path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        match stem.rsplit_once('_') {
            Some((head, tail))
                if !head.is_empty() && tail.chars().all(|c| c.is_ascii_alphanumeric()) && tail.len() <= 3 =>
            {
                head.to_string()
            }
            _ => stem,
        }
    }
}

/// Something left out, with why.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Skipped {
    /// The capture concerned, when the problem is a capture's.
    pub capture: Option<String>,
    pub what: String,
    pub reason: String,
}

/// The result of a scan.
#[derive(Debug, Clone)]
pub struct Scan {
    pub captures: Vec<Capture>,
    /// Band names in wavelength order (the complete set).
    pub band_names: Vec<String>,
    pub skipped: Vec<Skipped>,
    /// Thermal band files, left out (msnerf trains on the reflective bands): (file, band name).
    pub thermal: Vec<(PathBuf, String)>,
}

/// TIFF files under `dir` (recursive, sorted).
pub fn list_tiffs(dir: &Path) -> Result<Vec<PathBuf>, RigError> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).map_err(RigError::io(&d))? {
            let p = entry.map_err(RigError::io(&d))?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff")) {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Reads and interprets `files`, groups them into captures. Files that are not rig images are skipped (listed);
/// an error only when nothing usable is left, or cameras are mixed.
pub fn scan_files(files: &[PathBuf]) -> Result<Scan, RigError> {
    let mut skipped = Vec::new();
    let mut band_files: Vec<BandFile> = Vec::new();
    let mut first_error: Option<RigError> = None;
    let mut unreadable: Vec<&PathBuf> = Vec::new();
    let mut thermal = Vec::new();
    for f in files {
        match read_meta(f).and_then(interpret) {
            Ok(b) => band_files.push(b),
            Err(RigError::Thermal { path, band, .. }) => thermal.push((path, band)),
            Err(e) => {
                skipped.push(Skipped { capture: None, what: f.display().to_string(), reason: e.to_string() });
                first_error.get_or_insert(e);
                unreadable.push(f);
            }
        }
    }
    if band_files.is_empty() {
        return Err(first_error.unwrap_or_else(|| {
            RigError::option(
                "DIR",
                if thermal.is_empty() { "no TIFF files found" } else { "only thermal band files: no reflective band" },
            )
        }));
    }
    if let Some(other) = band_files.iter().find(|b| b.camera != band_files[0].camera) {
        return Err(RigError::Mixed {
            a: band_files[0].camera.clone(),
            a_path: band_files[0].meta.path.clone(),
            b: other.camera.clone(),
            b_path: other.meta.path.clone(),
        });
    }
    let mut groups: BTreeMap<String, Vec<BandFile>> = BTreeMap::new();
    for b in band_files {
        groups.entry(b.capture_key.clone()).or_default().push(b);
    }
    // The complete band set: every band name seen, by wavelength.
    let mut all: BTreeMap<String, f64> = BTreeMap::new();
    for g in groups.values() {
        for b in g {
            all.entry(b.band_name.clone()).or_insert(b.center_nm);
        }
    }
    let mut band_names: Vec<(String, f64)> = all.into_iter().collect();
    band_names.sort_by(|a, b| a.1.total_cmp(&b.1));
    let band_names: Vec<String> = band_names.into_iter().map(|b| b.0).collect();
    let readable_suffixes: std::collections::BTreeSet<String> =
        groups.values().flatten().filter_map(|b| band_file_parts(&b.meta.path).map(|(_, s)| s)).collect();
    let mut captures = Vec::new();
    for (key, mut files) in groups {
        files.sort_by(|a, b| a.center_nm.total_cmp(&b.center_nm));
        let names: Vec<&str> = files.iter().map(|b| b.band_name.as_str()).collect();
        let what = format!("capture {key} ({})", files[0].meta.path.display());
        let dup = names.iter().enumerate().find(|(i, n)| names[..*i].contains(n));
        if let Some((_, n)) = dup {
            skipped.push(Skipped { capture: Some(key.clone()), what, reason: format!("band {n} appears twice") });
            continue;
        }
        // A band file of this capture that could not be read (MicaSense names: IMG_0001_1.tif .. IMG_0001_5.tif)
        // takes the capture with it, where the same band suffix reads in another capture (the panel's, say): the
        // band belongs to the rig, so the capture is incomplete. A suffix that never reads (a band msnerf does not
        // take, such as a thermal one) leaves the captures alone.
        let captures_of: Vec<_> = files.iter().filter_map(|b| band_file_parts(&b.meta.path).map(|(c, _)| c)).collect();
        let of_this_capture = |u: &Path| {
            band_file_parts(u).is_some_and(|(c, s)| captures_of.contains(&c) && readable_suffixes.contains(&s))
        };
        if let Some(u) = unreadable.iter().find(|u| of_this_capture(u)) {
            let reason = format!("its band file {} could not be read", u.display());
            skipped.push(Skipped { capture: Some(key.clone()), what, reason });
            continue;
        }
        let missing: Vec<&String> = band_names.iter().filter(|n| !names.contains(&n.as_str())).collect();
        if !missing.is_empty() {
            let m: Vec<&str> = missing.iter().map(|s| s.as_str()).collect();
            skipped.push(Skipped {
                capture: Some(key.clone()),
                what,
                reason: format!("missing band(s) {}", m.join(", ")),
            });
            continue;
        }
        let size = (files[0].meta.width, files[0].meta.height);
        if let Some(b) = files.iter().find(|b| (b.meta.width, b.meta.height) != size) {
            skipped.push(Skipped {
                capture: Some(key.clone()),
                what,
                reason: format!(
                    "{} is {}x{}, the others {}x{}",
                    b.meta.path.display(),
                    b.meta.width,
                    b.meta.height,
                    size.0,
                    size.1
                ),
            });
            continue;
        }
        captures.push(Capture { key, bands: files });
    }
    captures.sort_by(|a, b| a.bands[0].meta.path.cmp(&b.bands[0].meta.path));
    Ok(Scan { captures, band_names, skipped, thermal })
}

/// A band file's capture (its folder and name without the band suffix) and its band suffix: `IMG_0001_3.tif` ->
/// ((folder, `IMG_0001`), `3`). The suffix is the last `_` part of the stem, one to three letters or digits, as
/// MicaSense (`_3`) and Parrot Sequoia (`_NIR`) name their band files.
fn band_file_parts(p: &Path) -> Option<((PathBuf, String), String)> {
    let stem = p.file_stem()?.to_str()?;
    let (prefix, suffix) = stem.rsplit_once('_')?;
    let band_like = (1..=3).contains(&suffix.len()) && suffix.chars().all(|c| c.is_ascii_alphanumeric());
    let folder = p.parent().unwrap_or(Path::new("")).to_path_buf();
    (band_like && !prefix.is_empty()).then(|| ((folder, prefix.to_owned()), suffix.to_owned()))
}
