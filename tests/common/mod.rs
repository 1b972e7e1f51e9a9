//! Shared test helpers: a GPU context that fails the test on any validation message, tolerance checks, and
//! seeded random data.
#![allow(dead_code)]

use msnerf::gpu::{Context, ContextDesc, Validation};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A context for one test. Validation is on whenever the layer is installed (required under `make test`,
/// which sets MSNERF_REQUIRE_VALIDATION=1); dropping it asserts that the layer reported nothing.
pub struct TestGpu {
    pub ctx: Context,
}

impl std::ops::Deref for TestGpu {
    type Target = Context;
    fn deref(&self) -> &Context {
        &self.ctx
    }
}

pub fn gpu() -> TestGpu {
    gpu_with(|_| {})
}

pub fn gpu_with(tweak: impl FnOnce(&mut ContextDesc)) -> TestGpu {
    let mut desc = ContextDesc::from_env();
    if desc.validation == Validation::Off {
        desc.validation = Validation::IfAvailable;
    }
    tweak(&mut desc);
    match Context::new(&desc) {
        Ok(ctx) => {
            if !ctx.validation_enabled() {
                eprintln!("note: VK_LAYER_KHRONOS_validation is not installed; this test runs without it (apt-get install vulkan-validationlayers)");
            }
            TestGpu { ctx }
        }
        Err(e) => panic!(
            "this test needs a Vulkan device and found none: {e}\n\
             Install Mesa's CPU driver lavapipe and the loader: run `bash tools/setup-debian.sh` as root, \
             or `apt-get install libvulkan1 mesa-vulkan-drivers vulkan-validationlayers`."
        ),
    }
}

impl Drop for TestGpu {
    fn drop(&mut self) {
        let msgs = self.ctx.validation_messages();
        if !msgs.is_empty() && !std::thread::panicking() {
            panic!("{} Vulkan validation message(s):\n{}", msgs.len(), msgs.join("\n"));
        }
    }
}

/// The fp32 kernel tolerance: |a - b| <= 1e-5 + 1e-4 |b| (b is the reference).
pub fn close_f32(a: f32, b: f32) -> bool {
    close(a as f64, b as f64, 1e-5, 1e-4)
}

pub fn close(a: f64, b: f64, atol: f64, rtol: f64) -> bool {
    a.is_finite() == b.is_finite() && (a - b).abs() <= atol + rtol * b.abs()
}

/// Asserts every element is within the fp32 tolerance, naming the first index that is not.
pub fn assert_all_close_f32(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: lengths differ");
    if let Some(i) = (0..got.len()).find(|&i| !close_f32(got[i], want[i])) {
        panic!("{what}: index {i}: got {} want {} (|diff| {:e})", got[i], want[i], (got[i] - want[i]).abs());
    }
}

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn random_f32(rng: &mut ChaCha8Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

pub fn random_u32(rng: &mut ChaCha8Rng, n: usize) -> Vec<u32> {
    (0..n).map(|_| rng.random()).collect()
}

/// Asserts two slices are equal, reporting only the first difference (never the whole slice).
pub fn assert_same<T: PartialEq + std::fmt::Debug>(got: &[T], want: &[T], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: lengths differ");
    if let Some(i) = (0..got.len()).find(|&i| got[i] != want[i]) {
        panic!("{what}: first difference at index {i}: got {:?} want {:?}", got[i], want[i]);
    }
}

/// A unique folder under the system temp dir, removed on drop.
pub struct TempDir(pub std::path::PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        let p = std::env::temp_dir().join(format!(
            "msnerf_{tag}_{}_{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("create a temp folder");
        TempDir(p)
    }

    pub fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Simulates the built-in `ci-small` scene (12 views of 64x48, 6 bands) into `dir`.
pub fn simulate_ci_small(dir: &std::path::Path) {
    let scene = msnerf::sim::SceneDesc::load("ci-small").expect("built-in scene");
    msnerf::sim::simulate(&scene, &msnerf::sim::SimOptions::default(), dir).expect("simulate");
}

/// Training options for tests: `model` on `data` into `out`, 1 GiB of image cache, `eval_pixels` held-out pixels,
/// no progress bar, no time budget.
pub fn train_options(
    data: &std::path::Path,
    out: &std::path::Path,
    model: msnerf::nerf::config::ModelConfig,
    eval_pixels: usize,
) -> msnerf::nerf::trainer::TrainOptions {
    msnerf::nerf::trainer::TrainOptions {
        data: data.to_path_buf(),
        model,
        out: out.to_path_buf(),
        resume: false,
        time_budget_s: None,
        host_budget_bytes: 1 << 30,
        resample_every: 500,
        eval_pixels,
        progress: false,
        stop: None,
        bands: None,
    }
}
