//! The host-memory plan: the training-image cache's bytes, its resident set N and resampling period M
//! (paper §6.1, Table 8), from the same rule the cache applies (`data::cache::plan_cache`).
//!
//! Table 8's rules, scaled to the host budget: N is as many training images as the cache budget holds (with one
//! image of decode scratch; all of them when they fit), and M = 2 N steps (Table 8: N 1000 / M 2000 on 256 GB,
//! N 2000 / M 4000 on 512 GB). A profile may fix N or M; a fixed N must fit the budget.

use super::hardware::{HostProfile, TABLE8_M_PER_N};
use crate::data::{cache::plan_cache, Dataset, Split};
use serde::Serialize;

/// The training process's own host memory besides the image cache: the binary, the Vulkan loader and driver (on
/// lavapipe its LLVM shader compiler), the dataset's tables and sparse points, the trainer's host-side batches.
/// Planned with a margin over what docs/results/flight.md measures.
pub const PROCESS_OVERHEAD_BYTES: u64 = 384 << 20;

/// What the plans need to know about a dataset.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct DatasetShape {
    /// Frames of the dataset (rows of the appearance embedding; of the camera table too, which with `rig_cameras`
    /// also holds every frame's band cameras: [`DatasetShape::table_cameras`]).
    pub n_frames: usize,
    /// Frames in the training split (what the cache holds).
    pub n_train: usize,
    pub width: u32,
    pub height: u32,
    pub bands: usize,
    /// Host bytes of the largest training image, mask plane included.
    pub bytes_per_image: u64,
    /// The dataset has `rig_cameras` (a camera per band of each frame in the camera table).
    pub rig_cameras: bool,
}

impl DatasetShape {
    pub fn from_dataset(ds: &Dataset) -> Self {
        let train = ds.split_indices(Split::Train);
        Self {
            n_frames: ds.frames.len(),
            n_train: train.len(),
            width: ds.width,
            height: ds.height,
            bands: ds.n_bands(),
            bytes_per_image: train.iter().map(|&i| ds.frame_bytes(i)).max().unwrap_or(0),
            rig_cameras: ds.rig.is_some(),
        }
    }

    /// A dataset described by numbers: `views` frames, all of them training frames, `sample_bytes` per sample.
    pub fn synthetic(views: usize, width: u32, height: u32, bands: usize, sample_bytes: u64) -> Self {
        Self {
            n_frames: views,
            n_train: views,
            width,
            height,
            bands,
            bytes_per_image: width as u64 * height as u64 * bands as u64 * sample_bytes,
            rig_cameras: false,
        }
    }

    /// Rows of the camera table the trainer uploads.
    pub fn table_cameras(&self) -> usize {
        self.n_frames * if self.rig_cameras { 1 + self.bands } else { 1 }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct HostPlan {
    pub n_images: usize,
    pub bytes_per_image: u64,
    /// Host bytes the cache may use (host memory minus headroom).
    pub budget_bytes: u64,
    /// N (0 when not even one image fits).
    pub n_resident: usize,
    /// M; None when every image is resident (nothing to resample).
    pub resample_every: Option<u64>,
    /// Resident images.
    pub resident_bytes: u64,
    /// Resident images plus one image of decode scratch: the cache's peak.
    pub peak_bytes: u64,
    /// The budget to hand the cache so that it keeps exactly N images.
    pub cache_budget_bytes: u64,
    pub fits_all: bool,
    pub problems: Vec<String>,
}

impl HostPlan {
    pub fn fits(&self) -> bool {
        self.problems.is_empty()
    }
}

pub fn plan_host(host: &HostProfile, budget_bytes: u64, ds: &DatasetShape) -> HostPlan {
    let per = ds.bytes_per_image.max(1);
    let mut problems = Vec::new();
    let auto = plan_cache(ds.n_train, per, budget_bytes);
    let max_n = auto.map_or(0, |p| p.n_resident);
    if auto.is_none() {
        problems.push(format!(
            "a host budget of {:.2} GiB cannot hold one image of {:.1} MiB plus decode scratch",
            budget_bytes as f64 / GIB,
            per as f64 / MIB
        ));
    }
    let n = match host.cache.n_resident {
        Some(n) if n.min(ds.n_train) > max_n => {
            problems.push(format!(
                "host.cache.n_resident = {n} needs {:.2} GiB; the host budget of {:.2} GiB holds {max_n} images",
                ((n.min(ds.n_train) as u64 + 1) * per) as f64 / GIB,
                budget_bytes as f64 / GIB
            ));
            n.min(ds.n_train)
        }
        Some(n) => n.min(ds.n_train),
        None => max_n,
    };
    let fits_all = n == ds.n_train && n > 0;
    let m = if fits_all { None } else { Some(host.cache.resample_every.unwrap_or((n as u64 * TABLE8_M_PER_N).max(1))) };
    HostPlan {
        n_images: ds.n_train,
        bytes_per_image: per,
        budget_bytes,
        n_resident: n,
        resample_every: m,
        resident_bytes: n as u64 * per,
        peak_bytes: (n as u64 + 1) * per,
        cache_budget_bytes: (n as u64 + 1) * per,
        fits_all,
        problems,
    }
}

const GIB: f64 = (1u64 << 30) as f64;
const MIB: f64 = (1u64 << 20) as f64;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::hardware::CacheProfile;

    fn host(n: Option<usize>) -> HostProfile {
        HostProfile { memory_gib: 1.0, headroom_gib: 0.0, cache: CacheProfile { n_resident: n, resample_every: None } }
    }

    #[test]
    fn n_follows_the_budget_and_m_is_twice_n() {
        let ds = DatasetShape::synthetic(100, 10, 10, 1, 1);
        let p = plan_host(&host(None), 1000, &ds);
        assert_eq!((p.n_resident, p.resample_every, p.peak_bytes), (9, Some(18), 1000));
        assert!(p.fits());
        let all = plan_host(&host(None), 1_000_000, &ds);
        assert_eq!((all.n_resident, all.resample_every, all.fits_all), (100, None, true));
        let fixed = plan_host(&host(Some(50)), 1000, &ds);
        assert!(!fixed.fits());
    }
}
