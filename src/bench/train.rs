//! `msnerf bench train`: milliseconds per training step, rays/s and the per-kernel time breakdown, for a model
//! profile at a given number of bands, on synthetic rays (a ring of cameras around the origin and random targets), so
//! the numbers depend only on the model, the batch and the device.
//!
//! The timed steps are steady-state steps by default: the pipeline's step counter starts past the proposal warm-up
//! and the weight annealing, so one step in `proposal_update_every` updates the proposal networks, as in most of a
//! run (`at_step` chooses another point). Each step draws a fresh batch (random pixels and targets, the trainer's
//! sampling work) and is submitted as the trainer does, with `trainer.steps_in_flight` steps in flight.
//!
//! Two passes of `steps` steps each: the first without timestamps gives the wall time per step (what training
//! costs); the second with a timestamp after every dispatch gives the GPU time and the per-kernel breakdown (its own
//! wall time is reported too: timestamps are not free). Host overhead = wall (first pass) - GPU time (second pass).
//! The host time of the first pass is split into recording, submission-to-signal waits, uploads, readbacks and the
//! batch sampling ([`crate::gpu::HostTimes`]).

use crate::data::camera::{Camera, CameraModel, Distortion};
use crate::gpu::TimingReport;
use crate::gpu::{Context, HostTimes, KernelTime};
use crate::nerf::config::ModelConfig;
use crate::nerf::model::Model;
use crate::nerf::pipeline::{Batch, Pipeline};
use crate::nerf::rays::GpuCamera;
use crate::nerf::{NerfError, NerfResult};
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::time::Instant;

#[derive(Clone, Debug, Serialize)]
pub struct TrainBench {
    pub model: String,
    pub bands: usize,
    pub rays_per_batch: usize,
    pub rays_per_chunk: usize,
    pub steps: usize,
    /// Steps submitted before the host waits for the oldest (`trainer.steps_in_flight`).
    pub steps_in_flight: usize,
    /// Wall time per step, no timestamps.
    pub ms_per_step: f64,
    /// Wall time per step of the profiled pass (a timestamp after every dispatch).
    pub ms_per_step_profiled: f64,
    pub rays_per_s: f64,
    pub kernels: Vec<KernelTime>,
    pub gpu_ms_per_step: f64,
    /// Wall minus GPU time per step.
    pub host_overhead_ms_per_step: f64,
    /// Host time per step by kind (recording, submit-to-signal, uploads, readbacks; submissions and waits).
    pub host: HostTimes,
    /// Batch sampling per step (milliseconds).
    pub sampling_ms_per_step: f64,
    /// Pipeline step counter of the first timed step.
    pub first_step: u64,
    /// Timed steps that updated the proposal networks.
    pub proposal_update_steps: usize,
    /// Whether the Vulkan validation layer was on (it slows recording).
    pub validation: bool,
    /// The device the steps ran on (`DeviceCaps::summary_line`: name, driver, limits).
    pub device: String,
    /// The MLP kernels the field ran (`MlpTiling`, as `summary.json` records it): fp32 tiles or tensor cores.
    pub mlp_tiling: String,
}

/// The first step past the proposal warm-up and the weight annealing (the steady state of a run).
pub fn steady_step(cfg: &ModelConfig) -> u64 {
    let s = &cfg.sampling;
    s.proposal_warmup.max(s.proposal_weights_anneal_max_num_iters).max(10) + 1
}

fn random_batch(rng: &mut rand_chacha::ChaCha8Rng, rays: usize, cameras: usize, bands: usize) -> Batch {
    let mut batch = Batch::default();
    for _ in 0..rays {
        batch.pixels.extend([rng.random_range(0..cameras as u32), rng.random_range(0..192), rng.random_range(0..256)]);
        batch.targets.extend((0..bands).map(|_| rng.random_range(0.0f32..1.0)));
        batch.targets.push(1.0);
    }
    batch
}

fn ring_cameras(n: usize) -> Vec<GpuCamera> {
    let cam = Camera {
        model: CameraModel::Pinhole,
        fx: 200.0,
        fy: 200.0,
        cx: 128.0,
        cy: 96.0,
        width: 256,
        height: 192,
        distortion: Distortion::default(),
    };
    (0..n)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / n as f32;
            let pos = [0.9 * a.cos(), 0.9 * a.sin(), 0.4];
            let l = (pos[0] * pos[0] + pos[1] * pos[1] + pos[2] * pos[2]).sqrt();
            let z = pos.map(|v| v / l);
            let xl = (z[0] * z[0] + z[1] * z[1]).sqrt();
            let x = [-z[1] / xl, z[0] / xl, 0.0];
            let y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
            GpuCamera::new(&cam, &[[x[0], y[0], z[0], pos[0]], [x[1], y[1], z[1], pos[1]], [x[2], y[2], z[2], pos[2]]])
        })
        .collect()
}

/// Runs `steps` timed training steps after `warmup` untimed ones, starting at pipeline step `at_step` (None: the
/// steady state, [`steady_step`]).
pub fn run(
    ctx: &Context,
    cfg: &ModelConfig,
    bands: usize,
    steps: usize,
    warmup: usize,
    at_step: Option<u64>,
) -> NerfResult<TrainBench> {
    let cams = ring_cameras(16);
    let model = Model::new(ctx, cfg, bands, cams.len())?;
    let mut pipe = Pipeline::new(ctx, model, &cams).map_err(NerfError::gpu("building the pipeline"))?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let r = cfg.trainer.rays_per_batch;
    pipe.step = at_step.unwrap_or_else(|| steady_step(cfg));
    // Every pipeline the steps use is created and compiled before the clock starts (the untimed steps below may
    // all skip the proposal update, whose kernels would otherwise compile inside the timed window).
    pipe.warm_up().map_err(NerfError::gpu("kernel warm-up"))?;
    for _ in 0..warmup {
        let batch = random_batch(&mut rng, r, cams.len(), bands);
        pipe.train_step(&batch).map_err(NerfError::gpu("warm-up step"))?;
    }
    let first_step = pipe.step;
    let mut timing = TimingReport::default();
    let (mut sampling_s, mut updates) = (0.0, 0);
    let mut pass =
        |profile_every: u64, sampling_s: &mut f64| -> NerfResult<(f64, Vec<crate::nerf::pipeline::StepStats>)> {
            pipe.profile_every = profile_every;
            let t = Instant::now();
            let mut done = Vec::new();
            for _ in 0..steps {
                let ts = Instant::now();
                let batch = random_batch(&mut rng, r, cams.len(), bands);
                *sampling_s += ts.elapsed().as_secs_f64();
                pipe.submit_step(&batch).map_err(NerfError::gpu("timed step"))?;
                done.extend(pipe.completed().map_err(NerfError::gpu("timed step"))?);
            }
            done.extend(pipe.flush().map_err(NerfError::gpu("timed step"))?);
            Ok((t.elapsed().as_secs_f64() * 1e3 / steps as f64, done))
        };
    let host0 = ctx.host_times();
    let (ms, done) = pass(0, &mut sampling_s)?;
    let host = ctx.host_times().since(&host0).per(steps);
    updates += done.iter().filter(|s| s.proposals_updated).count();
    let (ms_profiled, done) = pass(1, &mut 0.0)?;
    for st in &done {
        timing.accumulate(&st.timing);
    }
    let mut kernels = timing.by_kernel();
    for k in &mut kernels {
        k.total_ms /= steps as f64;
    }
    let gpu = timing.gpu_ms / steps as f64;
    Ok(TrainBench {
        model: cfg.name.clone(),
        bands,
        rays_per_batch: r,
        rays_per_chunk: cfg.trainer.rays_per_chunk,
        steps,
        steps_in_flight: pipe.steps_in_flight,
        ms_per_step: ms,
        ms_per_step_profiled: ms_profiled,
        rays_per_s: r as f64 / (ms / 1e3),
        kernels,
        gpu_ms_per_step: gpu,
        host_overhead_ms_per_step: ms - gpu,
        host,
        sampling_ms_per_step: sampling_s * 1e3 / steps as f64,
        first_step,
        proposal_update_steps: updates,
        validation: ctx.validation_enabled(),
        device: ctx.caps().summary_line(),
        mlp_tiling: format!("{:?}", pipe.model.field.mlp.tiling),
    })
}

impl TrainBench {
    pub fn table(&self) -> String {
        let mut s = format!(
            "{} with {} bands: {} rays/batch ({} per chunk, {} steps in flight): {:.1} ms/step, {:.0} rays/s (GPU time \
             {:.1} ms/step; {:.1} ms/step with timestamps)\n",
            self.model,
            self.bands,
            self.rays_per_batch,
            self.rays_per_chunk,
            self.steps_in_flight,
            self.ms_per_step,
            self.rays_per_s,
            self.gpu_ms_per_step,
            self.ms_per_step_profiled
        );
        let h = &self.host;
        s += &format!(
            "  {} steps from step {} ({} updated the proposals); validation layer {}; {}\n  host overhead {:.2} ms/step \
             ({:.1}% of the wall time): recording {:.2}, submit-to-signal {:.2} (GPU work included), uploads {:.2}, \
             readbacks {:.2}, batch sampling {:.2} ms; {} submissions and {} waits per step\n",
            self.steps,
            self.first_step,
            self.proposal_update_steps,
            if self.validation { "on" } else { "off" },
            self.device,
            self.host_overhead_ms_per_step,
            100.0 * self.host_overhead_ms_per_step / self.ms_per_step.max(1e-9),
            h.record_ms,
            h.submit_wait_ms,
            h.upload_ms,
            h.readback_ms,
            self.sampling_ms_per_step,
            h.submits,
            h.waits
        );
        for k in &self.kernels {
            s += &format!(
                "  {:<24} {:>5} calls {:>9.2} ms/step {:>6.1}%\n",
                k.name,
                k.count / self.steps as u32,
                k.total_ms,
                100.0 * k.total_ms / self.gpu_ms_per_step.max(1e-9)
            );
        }
        s
    }
}
