//! Cache benchmark: generates a synthetic rig dataset, then measures load throughput and the cache's
//! current/peak bytes across resampling under a budget. Prints one line per measurement.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::cache::{CacheConfig, ImageCache};
use super::loader::{load_dataset, LoadOptions};
use super::split::Split;
use super::synth::{write_synthetic_dataset, SynthSpec};

/// What one run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchResult {
    pub images_loaded: u64,
    pub load_seconds: f64,
    /// Decoded megabytes (10^6) per second, in stored type.
    pub load_mb_per_s: f64,
    pub budget_bytes: u64,
    pub peak_bytes: u64,
    pub n_resident: usize,
    pub n_train: usize,
    pub sample_rays_per_s: f64,
}

/// Runs the benchmark in `dir` (a temporary folder when `None`, removed afterwards).
pub fn run_cache_bench(
    dir: Option<&Path>,
    spec: SynthSpec,
    budget_bytes: u64,
    steps: u64,
    resample_every: u64,
) -> Result<BenchResult, String> {
    let tmp: PathBuf = match dir {
        Some(d) => d.to_path_buf(),
        None => std::env::temp_dir().join(format!("msnerf_bench_cache_{}", std::process::id())),
    };
    let t0 = Instant::now();
    write_synthetic_dataset(&tmp, &spec).map_err(|e| e.to_string())?;
    println!(
        "generated {} frames x {} bands {}x{} u16 in {:.2} s",
        spec.frames,
        spec.bands,
        spec.width,
        spec.height,
        t0.elapsed().as_secs_f64()
    );
    let ds = load_dataset(&tmp, &LoadOptions::default()).map_err(|e| e.to_string())?;
    let train = ds.split_indices(Split::Train);
    let cfg = CacheConfig { budget_bytes, resample_every, seed: 7 };
    let t1 = Instant::now();
    let mut cache = ImageCache::new(&ds, train.clone(), cfg).map_err(|e| e.to_string())?;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut sample_time = 0.0;
    let mut rays = 0u64;
    for _ in 0..steps {
        let ts = Instant::now();
        let b = cache.sample_pixels(&mut rng, 4096);
        sample_time += ts.elapsed().as_secs_f64();
        rays += b.row.len() as u64;
        cache.step().map_err(|e| e.to_string())?;
    }
    let total = t1.elapsed().as_secs_f64();
    let load_seconds = (total - sample_time).max(1e-9);
    let loaded_bytes = cache.loads() * ds.image_bytes();
    let r = BenchResult {
        images_loaded: cache.loads(),
        load_seconds,
        load_mb_per_s: loaded_bytes as f64 / 1e6 / load_seconds,
        budget_bytes,
        peak_bytes: cache.peak_bytes(),
        n_resident: cache.plan().n_resident,
        n_train: train.len(),
        sample_rays_per_s: rays as f64 / sample_time.max(1e-9),
    };
    println!(
        "cache: budget {} B, N = {} of {} train images, peak {} B ({:.1}% of budget), current {} B",
        r.budget_bytes,
        r.n_resident,
        r.n_train,
        r.peak_bytes,
        100.0 * r.peak_bytes as f64 / r.budget_bytes as f64,
        cache.current_bytes()
    );
    println!(
        "load: {} images in {:.2} s = {:.1} images/s, {:.1} MB/s decoded; sampling {:.2} M rays/s",
        r.images_loaded,
        r.load_seconds,
        r.images_loaded as f64 / r.load_seconds,
        r.load_mb_per_s,
        r.sample_rays_per_s / 1e6
    );
    if dir.is_none() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    Ok(r)
}
