//! Host image cache with an explicit byte budget (paper §6.1, Table 8): a resident set of N training images,
//! resampled every M steps, or all of them when they fit. Images stay in their compact stored type.
//!
//! Budget accounting: loading one image needs the image itself plus decode scratch (at most one more image:
//! planar reordering, band stacking, EXR channel interleaving), so
//! `N = floor(budget / bytes_per_image) − 1`, and `peak = resident + 2 · bytes_per_image` while loading.
//! Resampling first drops the images that leave, then loads the new ones one at a time, so the peak never
//! exceeds the budget. The resident set walks seeded random permutations of the training frames, so every
//! image is visited once every ceil(n / N) resamples.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::error::DataError;
use super::loader::Dataset;
use super::raster::Raster;

/// Budget and schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CacheConfig {
    /// Host bytes the cache may use at its peak.
    pub budget_bytes: u64,
    /// Resample the resident set every this many steps (M).
    pub resample_every: u64,
    /// Seed of the resampling RNG.
    pub seed: u64,
}

/// How many images the budget allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CachePlan {
    pub n_images: usize,
    /// N.
    pub n_resident: usize,
    pub bytes_per_image: u64,
    /// Resident bytes plus one image of decode scratch.
    pub peak_bytes: u64,
    pub fits_all: bool,
}

/// Computes N from the budget; `None` when not even one image fits.
pub fn plan_cache(n_images: usize, bytes_per_image: u64, budget_bytes: u64) -> Option<CachePlan> {
    let per = bytes_per_image.max(1);
    let slots = (budget_bytes / per).saturating_sub(1) as usize;
    if slots == 0 || n_images == 0 {
        return None;
    }
    let n_resident = slots.min(n_images);
    Some(CachePlan {
        n_images,
        n_resident,
        bytes_per_image: per,
        peak_bytes: (n_resident as u64 + 1) * per,
        fits_all: n_resident == n_images,
    })
}

/// Pixels drawn for one training batch.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PixelBatch {
    pub bands: usize,
    /// Dataset frame index of each pixel.
    pub image: Vec<u32>,
    pub row: Vec<u32>,
    pub col: Vec<u32>,
    /// `bands` f32 values per pixel.
    pub values: Vec<f32>,
    /// Mask value (0 only when the whole image is masked out).
    pub mask: Vec<u8>,
}

/// The resident set.
pub struct ImageCache<'a> {
    ds: &'a Dataset,
    frames: Vec<usize>,
    cfg: CacheConfig,
    plan: CachePlan,
    rng: ChaCha8Rng,
    queue: Vec<usize>,
    resident: Vec<(usize, Raster)>,
    step: u64,
    current: u64,
    peak: u64,
    loads: u64,
    visited: Vec<bool>,
}

impl<'a> ImageCache<'a> {
    /// Builds the cache over `frames` (dataset indices, usually the train split) and loads the first set.
    pub fn new(ds: &'a Dataset, frames: Vec<usize>, cfg: CacheConfig) -> Result<ImageCache<'a>, DataError> {
        let per = frames.iter().map(|&i| ds.frame_bytes(i)).max().unwrap_or(0);
        let plan = plan_cache(frames.len(), per, cfg.budget_bytes).ok_or_else(|| DataError::InvalidValue {
            path: ds.transforms_path.clone(),
            key: "cache budget".into(),
            frame: None,
            reason: format!(
                "a budget of {} bytes cannot hold one image of {per} bytes plus decode scratch ({} frames)",
                cfg.budget_bytes,
                frames.len()
            ),
        })?;
        let mut c = ImageCache {
            ds,
            visited: vec![false; frames.len()],
            frames,
            cfg,
            plan,
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            queue: Vec::new(),
            resident: Vec::new(),
            step: 0,
            current: 0,
            peak: 0,
            loads: 0,
        };
        c.resample()?;
        Ok(c)
    }

    pub fn plan(&self) -> &CachePlan {
        &self.plan
    }
    /// Bytes held now.
    pub fn current_bytes(&self) -> u64 {
        self.current
    }
    /// Highest bytes held (including decode scratch) since creation.
    pub fn peak_bytes(&self) -> u64 {
        self.peak
    }
    /// Images decoded so far.
    pub fn loads(&self) -> u64 {
        self.loads
    }
    /// Dataset indices of the resident images.
    pub fn resident_frames(&self) -> Vec<usize> {
        self.resident.iter().map(|r| r.0).collect()
    }
    /// The resident rasters with their dataset indices.
    pub fn resident(&self) -> &[(usize, Raster)] {
        &self.resident
    }
    /// Fraction of the cache's frames that have been resident at least once.
    pub fn visited_fraction(&self) -> f64 {
        self.visited.iter().filter(|&&v| v).count() as f64 / self.visited.len().max(1) as f64
    }

    /// Advances one training step; resamples every `resample_every` steps (never when all images fit).
    /// Returns whether it resampled.
    pub fn step(&mut self) -> Result<bool, DataError> {
        self.step += 1;
        if !self.plan.fits_all && self.cfg.resample_every > 0 && self.step % self.cfg.resample_every == 0 {
            self.resample()?;
            return Ok(true);
        }
        Ok(false)
    }

    fn next_set(&mut self) -> Vec<usize> {
        let n = self.plan.n_resident;
        let mut set: Vec<usize> = Vec::with_capacity(n);
        while set.len() < n {
            if self.queue.is_empty() {
                let mut perm: Vec<usize> = (0..self.frames.len()).collect();
                perm.shuffle(&mut self.rng);
                perm.reverse(); // popped from the back
                self.queue = perm;
            }
            let k = self.queue.pop().expect("refilled above");
            if !set.contains(&k) {
                set.push(k);
            }
        }
        set
    }

    /// Replaces the resident set with the next N images.
    pub fn resample(&mut self) -> Result<(), DataError> {
        let set = self.next_set();
        let keep: Vec<usize> = set.iter().map(|&k| self.frames[k]).collect();
        // Drop the leavers first so the peak stays within the budget.
        let old = std::mem::take(&mut self.resident);
        for (i, r) in old {
            if keep.contains(&i) {
                self.resident.push((i, r));
            } else {
                self.current -= r.bytes();
            }
        }
        for k in set {
            let fi = self.frames[k];
            self.visited[k] = true;
            if self.resident.iter().any(|r| r.0 == fi) {
                continue;
            }
            // The image being decoded plus one image of scratch.
            self.peak = self.peak.max(self.current + 2 * self.plan.bytes_per_image);
            let r = self.ds.read_frame(fi)?;
            self.loads += 1;
            self.current += r.bytes();
            self.peak = self.peak.max(self.current);
            self.resident.push((fi, r));
        }
        Ok(())
    }

    /// Draws `n` pixels uniformly over resident pixels (all images share one size), masks by rejection as
    /// nerfstudio does: up to 100 redraws, then a uniform choice among the image's unmasked pixels.
    pub fn sample_pixels<R: Rng + ?Sized>(&self, rng: &mut R, n: usize) -> PixelBatch {
        let b = self.ds.n_bands();
        let mut out = PixelBatch {
            bands: b,
            image: Vec::with_capacity(n),
            row: Vec::with_capacity(n),
            col: Vec::with_capacity(n),
            values: vec![0.0; n * b],
            mask: Vec::with_capacity(n),
        };
        if self.resident.is_empty() {
            return out;
        }
        let (w, h) = (self.ds.width, self.ds.height);
        for s in 0..n {
            let k = rng.random_range(0..self.resident.len());
            let (fi, r) = (&self.resident[k].0, &self.resident[k].1);
            let mut row = rng.random_range(0..h);
            let mut col = rng.random_range(0..w);
            let mut m = r.mask_at(row, col);
            let mut tries = 0;
            while m == 0 && tries < 100 {
                row = rng.random_range(0..h);
                col = rng.random_range(0..w);
                m = r.mask_at(row, col);
                tries += 1;
            }
            if m == 0 {
                if let Some(mask) = &r.mask {
                    let valid = mask.iter().filter(|&&v| v != 0).count();
                    if valid > 0 {
                        let pick = rng.random_range(0..valid);
                        let p = mask.iter().enumerate().filter(|(_, &v)| v != 0).nth(pick).map(|(p, _)| p).unwrap_or(0);
                        row = p as u32 / w;
                        col = p as u32 % w;
                        m = 1;
                    }
                }
            }
            out.image.push(*fi as u32);
            out.row.push(row);
            out.col.push(col);
            out.mask.push(m);
            r.pixel_into(row, col, &mut out.values[s * b..(s + 1) * b]);
        }
        out
    }
}
