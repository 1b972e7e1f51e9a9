//! Shared test helpers: a GPU context that fails the test on any validation message, tolerance checks, and
//! seeded random data.
#![allow(dead_code)]

use msnerf::gpu::{Context, ContextDesc, Validation};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io::Write;

/// A context for one test. Validation is on whenever the layer is installed (required under `make test`,
/// which sets MSNERF_REQUIRE_VALIDATION=1); dropping it asserts that the layer reported nothing.
///
/// A test process holds one device at a time: a test waits for the device lock before it opens its context. The
/// Khronos validation layer reads and writes its global map of dispatchable objects without a lock whenever a device
/// or instance is created or destroyed while another thread calls into the layer (KhronosGroup/Vulkan-ValidationLayers
/// issue 4391; Debian 12 ships 1.3.239). That race segfaulted the `kernels` binary once on lavapipe in CI
/// (2026-11-26) and the `outputs` binary within seconds with 16 test threads on an H200. msnerf opens one device per
/// process, so only the test harness, which opens one per test, meets it. Fields drop in order: the context first,
/// then the lock.
pub struct TestGpu {
    pub ctx: Context,
    _device: DeviceLock,
}

/// The process's device lock, re-entrant on one thread (a test may open two contexts side by side).
struct DeviceLock;

struct DeviceOwner {
    thread: Option<std::thread::ThreadId>,
    depth: usize,
    /// The holder's test name (its thread's name), since when it holds the device, and whether a waiter has said so.
    name: String,
    since: Option<std::time::Instant>,
    noted: bool,
}

static DEVICE_OWNER: std::sync::Mutex<DeviceOwner> =
    std::sync::Mutex::new(DeviceOwner { thread: None, depth: 0, name: String::new(), since: None, noted: false });
static DEVICE_FREED: std::sync::Condvar = std::sync::Condvar::new();

/// Once a test has held the device this long, one waiter says which test it is: with the device lock, one stuck test
/// holds up the rest, and the harness's "running for over 60 seconds" lines name every waiter alike (an H100,
/// 2026-11-28).
const HOLDER_NOTE_AFTER: std::time::Duration = std::time::Duration::from_secs(90);

impl DeviceLock {
    fn acquire() -> DeviceLock {
        let current = std::thread::current();
        let me = current.id();
        let mut o = DEVICE_OWNER.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            match o.thread {
                None => {
                    let name = current.name().unwrap_or("a test").to_owned();
                    let since = Some(std::time::Instant::now());
                    *o = DeviceOwner { thread: Some(me), depth: 1, name, since, noted: false };
                    return DeviceLock;
                }
                Some(t) if t == me => {
                    o.depth += 1;
                    return DeviceLock;
                }
                Some(_) => {
                    let held = o.since.map_or(std::time::Duration::ZERO, |s| s.elapsed());
                    if held >= HOLDER_NOTE_AFTER && !o.noted {
                        o.noted = true;
                        let note = format!(
                            "note: {} waits for the device, which {} has held for {} s\n",
                            current.name().unwrap_or("a test"),
                            o.name,
                            held.as_secs()
                        );
                        // Written without the lock held, straight to the stream: the harness captures eprintln! of
                        // tests that pass or hang.
                        drop(o);
                        let _ = std::io::stderr().write_all(note.as_bytes());
                        o = DEVICE_OWNER.lock().unwrap_or_else(|p| p.into_inner());
                        continue;
                    }
                    let wait = if o.noted { HOLDER_NOTE_AFTER } else { HOLDER_NOTE_AFTER.saturating_sub(held) };
                    let wait = wait.max(std::time::Duration::from_millis(10));
                    o = DEVICE_FREED.wait_timeout(o, wait).unwrap_or_else(|p| p.into_inner()).0;
                }
            }
        }
    }
}

impl Drop for DeviceLock {
    fn drop(&mut self) {
        let mut o = DEVICE_OWNER.lock().unwrap_or_else(|p| p.into_inner());
        o.depth -= 1;
        if o.depth == 0 {
            o.thread = None;
            o.since = None;
            DEVICE_FREED.notify_all();
        }
    }
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
    let device = DeviceLock::acquire();
    match Context::new(&desc) {
        Ok(ctx) => {
            if !ctx.validation_enabled() {
                eprintln!("note: VK_LAYER_KHRONOS_validation is not installed; this test runs without it (apt-get install vulkan-validationlayers)");
            }
            TestGpu { ctx, _device: device }
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

/// World z of ci-small's ground (its `world_offset`).
pub const GROUND_Z: f64 = 20.0;

/// Median of (true - rendered depth) / footprint over the pixels of every training view whose true surface point
/// lies on the ground plane (|z - ground| < 5 cm): positive = in front of (above) the ground.
pub fn ground_bias_footprints(run_dir: &std::path::Path) -> (f64, usize) {
    let g = gpu();
    let mut run = msnerf::nerf::run::LoadedRun::load(&g, run_dir).expect("load run");
    let mut rel = Vec::new();
    for f in run.ds.split_indices(msnerf::data::Split::Train) {
        let rv = run.render_view(f).expect("render");
        let truth = run.ds.read_depth(f).expect("depth").expect("ci-textured writes depth maps");
        let frame = &run.ds.frames[f];
        let focal = 0.5 * (frame.camera.fx + frame.camera.fy);
        let w = rv.width;
        for (q, (&t, &p)) in truth.iter().zip(&rv.depth).enumerate() {
            let ray = frame.camera.ray_f64(&frame.c2w, (q / w) as u32, (q % w) as u32);
            let z = ray.origin[2] + ray.direction[2] * t as f64;
            if (z - GROUND_Z).abs() < 0.05 {
                rel.push((t as f64 - p as f64) / (t as f64 / focal));
            }
        }
    }
    rel.sort_by(f64::total_cmp);
    (rel[rel.len() / 2], rel.len())
}

/// Runs the `msnerf` binary of this build; asserts success and returns stdout + stderr.
pub fn msnerf(bin: &str, args: &[&str]) -> String {
    let out = std::process::Command::new(bin).args(args).output().expect("run msnerf");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "msnerf {args:?}: {text}");
    text
}

/// Unit quaternion (w, x, y, z; Hamilton) of a rotation matrix, by Shepperd's method (the largest of w, x, y, z
/// is divided by, so no branch loses precision). Written from the formula, for the pose-import tests.
pub fn quaternion_of(r: [[f64; 3]; 3]) -> [f64; 4] {
    let tr = r[0][0] + r[1][1] + r[2][2];
    if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [(r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [(r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [(r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s]
    }
}

/// The `tiny` profile shrunk to a few-second whole-step test: 4 field levels (2^10 entries, max resolution 64),
/// 3 per proposal (2^9, 32), 12 / 6 proposal samples and 5 NeRF samples. Tests set their own batch sizes.
pub fn small_tiny_config() -> msnerf::nerf::config::ModelConfig {
    let mut c = msnerf::nerf::config::ModelConfig::resolve("tiny").expect("tiny model");
    c.field.grid.n_levels = 4;
    c.field.grid.log2_hashmap_size = 10;
    c.field.grid.max_resolution = 64;
    for p in &mut c.proposals {
        p.grid.n_levels = 3;
        p.grid.log2_hashmap_size = 9;
        p.grid.max_resolution = 32;
    }
    c.proposals[0].samples = 12;
    c.proposals[1].samples = 6;
    c.sampling.num_nerf_samples = 5;
    c
}
