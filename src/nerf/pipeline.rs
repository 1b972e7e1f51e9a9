//! One nerfacto training step and the evaluation render, on the GPU (spec/nerfacto.md §2.14, §2.17).
//! A batch of rays is processed in chunks of `rays_per_chunk`; gradients of all chunks add up in the parameter store,
//! then Adam steps the groups that received gradients (proposals only on update steps).
//!
//! A training step is one submission (issue 22): the batch is written into a persistent host buffer
//! ([`super::step_io`]), and the command buffer copies each chunk's inputs in, runs it, copies its outputs out, then
//! runs the pose regulariser, the NaN/Inf guard ([`super::guard`]) and Adam, gated on the guard's flag. Up to
//! `trainer.steps_in_flight` steps are submitted before the host waits for the oldest ([`Pipeline::submit_step`],
//! [`Pipeline::completed`], [`Pipeline::flush`]); [`Pipeline::train_step`] is one step, waited for.
//!
//! Per chunk: copy pixels and targets in -> `ray_gen` -> for each proposal level: sample (initial or PDF) -> hash grid ->
//! MLP -> weights -> NeRF level: PDF sample -> hash grid -> density MLP -> colour input -> colour MLP -> `composite`
//! (loss and dL/draw, dL/dc) -> colour MLP backward -> geometric-feature and appearance gradients -> density MLP
//! backward -> hash grid backward; on proposal-update steps `interlevel` -> proposal MLP and hash grid backward.

use super::buffers::{Backward, ChunkBuffers, GpuAlloc, RayOut, RAY_OUT_FIXED};
use super::config::Background;
use super::guard::Guard;
use super::kernels::{
    BackgroundMode, CompositeBuffers, CompositeParams, Geometry, InterlevelBuffers, Jitter, RayBuffers, RenderKernels,
};
use super::model::Model;
use super::pose::{LevelGrad, PoseKernels, PoseSlot};
use super::rays::GpuCamera;
use super::schedule::{anneal_at, ProposalSchedule};
use super::step_io::{StepIo, StepLayout};
use crate::gpu::staging::Part;
use crate::gpu::{Context, GpuBuffer, GpuError, GpuResult, InFlight, MemoryCategory, Recorder, TimingReport};
use crate::nn::{ParamSlice, RowSlice};
use std::collections::VecDeque;

/// A training batch: per ray (camera, row, col) and B target values plus a ray weight (0 masks the ray out); a NaN
/// target is a band the ray did not observe (rig-aware training, [`super::rig_rays`]): it adds nothing to the loss
/// (an infinite one is corrupt data, and the NaN/Inf guard skips the step). With depth supervision on, per ray (target distance, sigma) in the normalised frame, (0, 1) for no
/// target.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    pub pixels: Vec<u32>,
    /// Per ray, the camera whose pose correction and appearance embedding it uses (its frame); empty: the camera
    /// of its pixel triple.
    pub cameras: Vec<u32>,
    pub targets: Vec<f32>,
    /// Empty unless `loss.depth` is set; then (distance, sigma) per ray, distance 0 where the ray has no target.
    pub depth: Vec<f32>,
}

impl Batch {
    pub fn rays(&self) -> usize {
        self.pixels.len() / 3
    }

    /// Per ray, the camera of its per-camera parameters.
    pub fn ray_cameras(&self) -> Vec<u32> {
        if self.cameras.is_empty() {
            self.pixels.chunks(3).map(|p| p[0]).collect()
        } else {
            self.cameras.clone()
        }
    }

    /// Targets per ray: the bands and the ray's weight.
    fn target_stride(&self) -> usize {
        self.targets.len() / self.rays().max(1)
    }

    /// Ray `i`'s pixel: (camera or frame, row, column).
    pub fn pixel(&self, i: usize) -> [u32; 3] {
        [self.pixels[3 * i], self.pixels[3 * i + 1], self.pixels[3 * i + 2]]
    }

    /// Ray `i`'s band targets (NaN: the band is not observed there).
    pub fn band_targets(&self, i: usize) -> &[f32] {
        let s = self.target_stride();
        &self.targets[i * s..(i + 1) * s - 1]
    }

    /// Ray `i`'s band targets, to change them (tests corrupt one this way).
    pub fn band_targets_mut(&mut self, i: usize) -> &mut [f32] {
        let s = self.target_stride();
        &mut self.targets[i * s..(i + 1) * s - 1]
    }

    /// Ray `i`'s weight in the loss (0: the ray does not count).
    pub fn ray_weight(&self, i: usize) -> f32 {
        let s = self.target_stride();
        self.targets[(i + 1) * s - 1]
    }

    /// Ray `i`'s depth target (distance along the ray, sigma), None without depth supervision or where the ray has
    /// no target.
    pub fn depth_target(&self, i: usize) -> Option<(f32, f32)> {
        let d = self.depth.get(2 * i..2 * i + 2)?;
        (d[0] > 0.0).then_some((d[0], d[1]))
    }

    /// The (ray, band) targets that count: the sum over rays of the ray weight times its observed bands (eq. 3.1's
    /// normaliser: the loss is the weighted mean over observed targets).
    pub fn observed_targets(&self, bands: usize) -> f64 {
        self.targets
            .chunks(bands + 1)
            .map(|t| t[bands] as f64 * t[..bands].iter().filter(|v| !v.is_nan()).count() as f64)
            .sum()
    }
}

#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StepStats {
    pub step: u64,
    pub loss: f64,
    pub loss_rgb: f64,
    pub loss_distortion: f64,
    pub loss_interlevel: f64,
    /// Depth supervision (0 without `loss.depth`).
    pub loss_depth: f64,
    /// Camera pose regulariser (0 without pose refinement).
    pub loss_pose: f64,
    /// PSNR of the batch (data range 1) from the unweighted squared error.
    pub psnr: f64,
    pub proposals_updated: bool,
    /// Learning rate of the `fields` group at this step (its schedule, `optimizer.schedule`).
    pub lr_fields: f64,
    /// The step was skipped by the NaN/Inf guard; `poisoned` names the first non-finite buffer.
    pub skipped: bool,
    pub poisoned: Option<String>,
    /// The step carried per-dispatch timestamps (`timing.gpu_ms` and the dispatch list are filled).
    pub profiled: bool,
    #[serde(skip)]
    pub timing: TimingReport,
}

/// A submitted training step waiting for its results.
struct PendingStep {
    io: usize,
    flight: InFlight,
    stats: StepStats,
    n_rays: usize,
    /// [`Batch::observed_targets`] (at least B).
    observed: f64,
    n_reg: usize,
    /// What Adam's host counters did (taken back if the guard skipped the step).
    adam: Vec<crate::nn::adam::GroupStep>,
}

/// Rendered rays (evaluation).
#[derive(Clone, Debug, Default)]
pub struct RenderOut {
    /// R x B
    pub colour: Vec<f32>,
    pub accumulation: Vec<f32>,
    pub median_depth: Vec<f32>,
    pub expected_depth: Vec<f32>,
    /// Where the accumulation crosses 0.25 and 0.75 of its total (normalised-frame distance along the unit ray):
    /// q75 - q25 is how spread the ray's weights are.
    pub depth_q25: Vec<f32>,
    pub depth_q75: Vec<f32>,
    /// |direction| before normalisation, for z-depth conversion
    pub direction_norm: Vec<f32>,
    pub timing: TimingReport,
}

pub struct Pipeline {
    pub ctx: Context,
    pub model: Model,
    kernels: RenderKernels,
    /// Present when the camera optimiser is on.
    pose_kernels: Option<PoseKernels>,
    cameras: GpuBuffer<GpuCamera>,
    /// The NaN/Inf guard's flags (allocated with the training buffers).
    guard: Option<Guard>,
    /// One set of step host buffers per step in flight (a ring).
    io: Vec<StepIo>,
    next_io: usize,
    pending: VecDeque<PendingStep>,
    finished: VecDeque<StepStats>,
    /// Steps submitted before the host waits for the oldest (`trainer.steps_in_flight`).
    pub steps_in_flight: usize,
    /// Per-dispatch timestamps on one step in this many (0: never; 1: every step).
    pub profile_every: u64,
    train_bufs: Option<ChunkBuffers<GpuAlloc>>,
    eval_bufs: Option<ChunkBuffers<GpuAlloc>>,
    pub schedule: ProposalSchedule,
    /// The training step the next step records (and evaluation renders at: `field.coarse_to_fine`'s levels).
    pub step: u64,
    /// Cameras the pose regulariser averages over (the training split; defaults to every camera).
    pub n_train_cameras: usize,
    /// Camera rows whose appearance embeddings trained (the training split): evaluation averages these only, as
    /// nerfstudio does; eval frames' rows never receive a gradient and stay at their random initialisation.
    /// None: every row.
    pub appearance_rows: Option<Vec<usize>>,
}

impl Drop for Pipeline {
    /// Steps still in flight use the model's buffers and the step host buffers: wait for them before any field
    /// is freed (fields drop in declaration order, `pending` after those).
    fn drop(&mut self) {
        self.pending.clear();
    }
}

fn need<T>(o: &Option<T>) -> &T {
    o.as_ref().expect("training buffers are allocated with train = true")
}

/// The hidden-layer scratch of an MLP's inference: its training activations, or the chunk's inference scratch.
fn infer_scratch<'a>(train: &'a Option<Backward<GpuAlloc>>, b: &'a ChunkBuffers<GpuAlloc>) -> &'a GpuBuffer<f32> {
    let acts = train.as_ref().map(|t| &t.acts);
    acts.or(b.mlp_scratch.as_ref()).expect("inference buffers have the MLP scratch, training ones activations")
}

impl Pipeline {
    /// Moves to `step` (a loaded run's last trained step): the field grid's coarse-to-fine levels follow, also for
    /// work recorded outside a render (normals). Each recorded forward sets them from `step` again, since training
    /// advances the step without this call.
    pub fn set_step(&mut self, step: u64) {
        self.step = step;
        self.model.field.grid.set_active_levels(self.model.cfg.field.active_levels_at(step));
    }

    /// `cameras`: the camera table in the normalised frame: one entry per dataset frame, then (`rig_cameras`) every
    /// frame's band cameras ([`super::rig_rays::RigRays::table`]).
    pub fn new(ctx: &Context, model: Model, cameras: &[GpuCamera]) -> GpuResult<Self> {
        super::kernels::check_bands(model.bands)?;
        let kernels = RenderKernels::new(ctx)?;
        let cameras = GpuBuffer::from_slice(ctx, "camera table", MemoryCategory::Rays, cameras)?;
        let pose_kernels = if model.cfg.camera_optimizer.enabled() { Some(PoseKernels::new(ctx)?) } else { None };
        let n_train_cameras = model.n_cameras;
        let steps_in_flight = model.cfg.trainer.steps_in_flight.clamp(1, 3);
        Ok(Self {
            ctx: ctx.clone(),
            model,
            kernels,
            pose_kernels,
            cameras,
            guard: None,
            io: Vec::new(),
            next_io: 0,
            pending: VecDeque::new(),
            finished: VecDeque::new(),
            steps_in_flight,
            profile_every: 1,
            train_bufs: None,
            eval_bufs: None,
            schedule: ProposalSchedule::default(),
            step: 0,
            n_train_cameras,
            appearance_rows: None,
        })
    }

    /// Replaces the camera table. Rendering novel views appends their cameras after the dataset's cameras (indices
    /// `>= model.n_cameras` are valid for [`Pipeline::render`] only: evaluation uses no pose correction and the mean
    /// appearance embedding, so no per-camera parameter is read for them). Training keeps the dataset's table.
    pub fn set_cameras(&mut self, cameras: &[GpuCamera]) -> GpuResult<()> {
        self.cameras = GpuBuffer::from_slice(&self.ctx, "camera table", MemoryCategory::Rays, cameras)?;
        Ok(())
    }

    /// The pose slot, when poses are refined.
    fn pose_slot(&self) -> Option<PoseSlot<'_>> {
        let store = &self.model.store;
        let slot = self.model.slots.pose.as_ref()?;
        Some(PoseSlot { params: store.params(), grads: store.grads(), offset: slot.offset })
    }

    fn geometry(&self, eval: bool) -> Geometry {
        let s = &self.model.cfg.sampling;
        Geometry { near: if eval { 0.0 } else { s.near }, far: s.far, contraction: s.scene_contraction }
    }

    fn background(&self, train: bool) -> BackgroundMode {
        match self.model.cfg.rendering.background_at(self.step, train) {
            Background::LastSample => BackgroundMode::LastSample,
            Background::Black => BackgroundMode::Constant(0.0),
            Background::White => BackgroundMode::Constant(1.0),
            Background::Random if train => {
                BackgroundMode::Random { seed: self.model.cfg.trainer.seed as u32, step: self.step as u32 }
            }
            Background::Random => BackgroundMode::Constant(0.0),
        }
    }

    fn ensure_buffers(&mut self, train: bool) -> GpuResult<()> {
        let t = &self.model.cfg.trainer;
        let (slot, rays) =
            if train { (&mut self.train_bufs, t.rays_per_chunk) } else { (&mut self.eval_bufs, t.eval_rays_per_chunk) };
        if slot.is_none() {
            let b = ChunkBuffers::new(&mut GpuAlloc(self.ctx.clone()), &self.model, rays, train)?;
            let bw = self
                .model
                .cfg
                .band_weights(self.model.bands)
                .map_err(|e| GpuError::Config { what: "band weights".into(), msg: e.to_string() })?;
            self.ctx.upload(&b.band_weights, 0, &bw)?;
            *slot = Some(b);
        }
        if train && self.guard.is_none() {
            let chunks = self.model.store.grads().chunks().len();
            self.guard = Some(Guard::new(&self.ctx, self.model.proposals.len(), chunks)?);
        }
        Ok(())
    }

    /// The layout of a step's host buffers for `rays` rays.
    fn step_layout(&self, rays: usize) -> StepLayout {
        let words = self.guard.as_ref().map_or(1, |g| g.words());
        StepLayout::new(rays, self.model.bands, self.model.proposals.len(), words, self.model.n_cameras)
    }

    /// The ring of step host buffers: `steps_in_flight` of them, each for a full batch (`rays` if larger).
    /// Only called with no step in flight, or for the slot about to be used.
    fn ensure_io(&mut self, slot: usize, rays: usize) -> GpuResult<()> {
        let want = self.step_layout(rays.max(self.model.cfg.trainer.rays_per_batch));
        while self.io.len() < self.steps_in_flight {
            self.io.push(StepIo::new(&self.ctx, want)?);
        }
        if self.io[slot].layout.rays < rays {
            self.io[slot] = StepIo::new(&self.ctx, self.step_layout(rays))?;
        }
        Ok(())
    }

    /// Records the forward pass of one chunk (all levels, up to the colour MLP). `train` stores activations.
    fn record_forward(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        (r, ray_offset): (usize, usize),
        train: bool,
        update_props: bool,
    ) -> GpuResult<()> {
        let m = &self.model;
        let k = &self.kernels;
        let store = &m.store;
        let params = store.params();
        let eval = !train;
        let geo = self.geometry(eval);
        let rb = RayBuffers { origins: &b.origins, dirs: &b.dirs, n_rays: r, ray_offset: ray_offset as u32 };
        let seed = m.cfg.trainer.seed as u32;
        let jit =
            |level: u32| Jitter { seed, step: self.step as u32, level, enabled: train && m.cfg.sampling.single_jitter };
        let anneal = if train { anneal_at(&m.cfg.sampling, self.step) } else { 1.0 };
        m.field.grid.set_active_levels(m.cfg.field.active_levels_at(self.step));
        let scale = m.cfg.field.average_init_density;
        k.ray_gen(rec, &self.cameras, &b.pixels, rb, &b.norms)?;
        if let (true, Some(pk), Some(slot), Some(pb)) = (train, self.pose_kernels.as_ref(), self.pose_slot(), &b.pose) {
            pk.apply(rec, slot, &b.cam_idx, rb, &pb.raw_dirs)?;
        }
        // Proposal levels.
        let mut prev: Option<(&GpuBuffer<f32>, &GpuBuffer<f32>, usize)> = None;
        for (p, (lv, field)) in b.proposals.iter().zip(&m.proposals).enumerate() {
            match prev {
                None => k.sample_initial(rec, rb, geo, lv.n, jit(0), (&lv.edges, &lv.positions))?,
                Some((e, w, n)) => {
                    k.pdf_resample(rec, rb, geo, (n, lv.n), anneal, jit(p as u32), (e, w), (&lv.edges, &lv.positions))?
                }
            }
            let s = r * lv.n;
            let gp = ParamSlice { array: params, offset: field.grid_offset };
            field.grid.forward(rec, gp, &lv.positions, s, &lv.enc, field.enc_slot)?;
            let mp = ParamSlice { array: params, offset: field.mlp_offset };
            let input = RowSlice { buf: &lv.enc, stride: field.enc_slot.stride, col: 0 };
            let out = RowSlice { buf: &lv.raw, stride: 1, col: 0 };
            if train && update_props {
                field.mlp.forward(rec, mp, input, s, out, &need(&lv.train).acts)?;
            } else {
                field.mlp.infer(rec, mp, input, s, out, infer_scratch(&lv.train, b))?;
            }
            k.weights(rec, rb, geo, lv.n, &lv.edges, (&lv.raw, 1), scale, &lv.weights)?;
            prev = Some((&lv.edges, &lv.weights, lv.n));
        }
        // NeRF level.
        let lv = &b.nerf;
        let level = m.proposals.len() as u32;
        match prev {
            None => k.sample_initial(rec, rb, geo, lv.n, jit(0), (&lv.edges, &lv.positions))?,
            Some((e, w, n)) => {
                k.pdf_resample(rec, rb, geo, (n, lv.n), anneal, jit(level), (e, w), (&lv.edges, &lv.positions))?
            }
        }
        let s = r * lv.n;
        let f = &m.field;
        f.grid.forward(
            rec,
            ParamSlice { array: params, offset: f.grid_offset },
            &lv.positions,
            s,
            &lv.enc,
            f.enc_slot,
        )?;
        let fm = &f.mlp.config;
        let mp = ParamSlice { array: params, offset: f.mlp_offset };
        let input = RowSlice { buf: &lv.enc, stride: fm.in_pad(), col: 0 };
        let out = RowSlice { buf: &lv.raw, stride: fm.n_output, col: 0 };
        if train {
            f.mlp.forward(rec, mp, input, s, out, &need(&lv.train).acts)?;
        } else {
            f.mlp.infer(rec, mp, input, s, out, infer_scratch(&lv.train, b))?;
        }
        let geo_dim = m.cfg.field.geo_feat_dim;
        let app_dim = m.cfg.field.appearance_embed_dim;
        let cm = &m.colour.config;
        let app = if app_dim > 0 {
            let slot = m.slots.appearance.as_ref().expect("appearance slot exists when the module is on");
            let binding = store.slot_binding(params, slot)?;
            Some((binding, &b.cam_idx, app_dim, if train { None } else { Some(m.n_cameras as u32) }))
        } else {
            None
        };
        let sh = m.cfg.field.sh_count();
        k.colour_input(rec, rb, lv.n, (&lv.raw, fm.n_output), geo_dim, sh, app, (&b.colour.input, cm.in_pad()))?;
        let cp = ParamSlice { array: params, offset: m.slots.colour_mlp.offset };
        let cin = RowSlice { buf: &b.colour.input, stride: cm.in_pad(), col: 0 };
        let cout = RowSlice { buf: &b.colour.out, stride: m.bands, col: 0 };
        if train {
            m.colour.forward(rec, cp, cin, s, cout, &need(&b.colour.train).acts)
        } else {
            m.colour.infer(rec, cp, cin, s, cout, infer_scratch(&b.colour.train, b))
        }
    }

    /// Backward of one density field over `s` samples: its MLP (from dL/draw rows to dL/dencoding, adding weight
    /// gradients) then its hash grid's parameter gradient. The NeRF density field and every proposal share it.
    fn record_density_backward(
        &self,
        rec: &mut Recorder,
        field: &super::model::DensityField,
        lv: &super::buffers::LevelBuffers<GpuAlloc>,
        s: usize,
    ) -> GpuResult<()> {
        let m = &self.model;
        let (params, grads) = (m.store.params(), m.store.grads());
        let c = &field.mlp.config;
        let mp = ParamSlice { array: params, offset: field.mlp_offset };
        let mg = ParamSlice { array: grads, offset: field.mlp_offset };
        let input = RowSlice { buf: &lv.enc, stride: c.in_pad(), col: 0 };
        let out = RowSlice { buf: &lv.raw, stride: c.n_output, col: 0 };
        let dy = RowSlice { buf: &need(&lv.train).dy, stride: c.n_output, col: 0 };
        let dx = RowSlice { buf: &need(&lv.train).dx, stride: c.in_pad(), col: 0 };
        let bufs = crate::nn::mlp::MlpTrainBuffers {
            acts: &need(&lv.train).acts,
            deltas: &need(&lv.train).deltas,
            scratch: &need(&lv.train).scratch,
        };
        field.mlp.backward(rec, mp, mg, (input, out, dy), s, &bufs, Some(dx))?;
        field.grid.backward_params(rec, ParamSlice { array: grads, offset: field.grid_offset }, &lv.positions, s, dx)
    }

    /// Records composite + backward of one training chunk.
    fn record_backward(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        (r, ray_offset): (usize, usize),
        norms: (f32, f32, f32, f32),
        update_props: bool,
    ) -> GpuResult<()> {
        let m = &self.model;
        let k = &self.kernels;
        let store = &m.store;
        let (params, grads) = (store.params(), store.grads());
        let geo = self.geometry(false);
        let rb = RayBuffers { origins: &b.origins, dirs: &b.dirs, n_rays: r, ray_offset: ray_offset as u32 };
        let scale = m.cfg.field.average_init_density;
        let lv = &b.nerf;
        let f = &m.field;
        let fm = &f.mlp.config;
        let (rgb_norm, dist_norm, inter_norm, depth_norm) = norms;
        let p = CompositeParams {
            bands: m.bands,
            density_stride: fm.n_output,
            density_scale: scale,
            background: self.background(true),
            rgb_norm,
            dist_norm,
            train: true,
            grad_scaling: m.cfg.loss.gradient_scaling,
            depth: m.cfg.loss.depth.map(|d| (d.loss, depth_norm)),
        };
        let cb = CompositeBuffers {
            edges: &lv.edges,
            density: &lv.raw,
            colours: &b.colour.out,
            targets: &b.targets,
            band_weights: &b.band_weights,
            dy_density: &need(&lv.train).dy,
            dy_colour: &need(&b.colour.train).dy,
            weights: &lv.weights,
            ray_out: &b.ray_out,
            depth_targets: b.depth_targets.as_ref(),
        };
        k.composite(rec, rb, geo, lv.n, &p, &cb)?;
        let s = r * lv.n;
        let cm = &m.colour.config;
        let cp = ParamSlice { array: params, offset: m.slots.colour_mlp.offset };
        let cg = ParamSlice { array: grads, offset: m.slots.colour_mlp.offset };
        let cin = RowSlice { buf: &b.colour.input, stride: cm.in_pad(), col: 0 };
        let cout = RowSlice { buf: &b.colour.out, stride: m.bands, col: 0 };
        let cdy = RowSlice { buf: &need(&b.colour.train).dy, stride: m.bands, col: 0 };
        let cdx = RowSlice { buf: &need(&b.colour.train).dx, stride: cm.in_pad(), col: 0 };
        let cbufs = crate::nn::mlp::MlpTrainBuffers {
            acts: &need(&b.colour.train).acts,
            deltas: &need(&b.colour.train).deltas,
            scratch: &need(&b.colour.train).scratch,
        };
        m.colour.backward(rec, cp, cg, (cin, cout, cdy), s, &cbufs, Some(cdx))?;
        let geo_dim = m.cfg.field.geo_feat_dim;
        let sh_dim = crate::nn::sh::SH_DIM;
        k.copy_cols(
            rec,
            s,
            geo_dim,
            (&need(&b.colour.train).dx, cm.in_pad(), sh_dim),
            (&need(&lv.train).dy, fm.n_output, 1),
        )?;
        let app_dim = m.cfg.field.appearance_embed_dim;
        if app_dim > 0 {
            let off = m.slots.appearance.as_ref().expect("appearance slot exists when the module is on").offset;
            k.appearance_grad(
                rec,
                grads,
                off,
                (r, lv.n),
                app_dim,
                (&need(&b.colour.train).dx, cm.in_pad(), sh_dim + geo_dim),
                &b.cam_idx,
            )?;
        }
        self.record_density_backward(rec, f, lv, s)?;
        let cdx = (&need(&b.colour.train).dx, cm.in_pad());
        self.record_pose_level(rec, b, rb, f, lv, Some(cdx), false)?;
        if !update_props {
            return self.record_pose_reduce(rec, b, r);
        }
        for (pl, field) in b.proposals.iter().zip(&m.proposals) {
            let ib = InterlevelBuffers {
                nerf_edges: &lv.edges,
                nerf_weights: &lv.weights,
                prop_edges: &pl.edges,
                prop_raw: &pl.raw,
                prop_weights: &pl.weights,
                prop_dy: &need(&pl.train).dy,
                losses: need(&pl.losses),
            };
            k.interlevel(rec, rb, geo, (lv.n, pl.n), 1, scale, inter_norm, &ib)?;
            self.record_density_backward(rec, field, pl, r * pl.n)?;
            self.record_pose_level(rec, b, rb, field, pl, None, true)?;
        }
        self.record_pose_reduce(rec, b, r)
    }

    /// Pose refinement, one level: dL/dhash input of its samples, then each ray's (dL/dorigin, dL/ddirection).
    #[allow(clippy::too_many_arguments)]
    fn record_pose_level(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        rb: RayBuffers,
        field: &super::model::DensityField,
        lv: &super::buffers::LevelBuffers<GpuAlloc>,
        colour_dx: Option<(&GpuBuffer<f32>, usize)>,
        accumulate: bool,
    ) -> GpuResult<()> {
        let (Some(pk), Some(pb)) = (self.pose_kernels.as_ref(), &b.pose) else { return Ok(()) };
        let m = &self.model;
        let s = rb.n_rays * lv.n;
        let gp = ParamSlice { array: m.store.params(), offset: field.grid_offset };
        let dx = RowSlice { buf: &need(&lv.train).dx, stride: field.mlp.config.in_pad(), col: 0 };
        field.grid.backward_input(rec, gp, &lv.positions, s, dx, &pb.dpos)?;
        let sh_count = m.cfg.field.sh_count();
        let level = LevelGrad { n: lv.n, edges: &lv.edges, dpos: &pb.dpos, colour_dx, sh_count, accumulate };
        pk.ray_grad(rec, rb, self.geometry(false), &level, &b.dummy, &pb.ray_grads)
    }

    /// Pose refinement: adds every ray's share to its camera's gradient.
    fn record_pose_reduce(&self, rec: &mut Recorder, b: &ChunkBuffers<GpuAlloc>, r: usize) -> GpuResult<()> {
        let (Some(pk), Some(slot), Some(pb)) = (self.pose_kernels.as_ref(), self.pose_slot(), &b.pose) else {
            return Ok(());
        };
        pk.reduce(rec, slot, (&pb.ray_grads, &pb.raw_dirs, &b.cam_idx), r)
    }

    /// Pose refinement: records the regulariser (its gradient is added to the pose slot, its per-camera losses go
    /// to `reg_losses`); returns how many losses to read back (0 without refinement).
    fn record_pose_regularizer(&self, rec: &mut Recorder, b: &ChunkBuffers<GpuAlloc>) -> GpuResult<usize> {
        let (Some(pk), Some(slot), Some(pb)) = (self.pose_kernels.as_ref(), self.pose_slot(), &b.pose) else {
            return Ok(0);
        };
        let co = &self.model.cfg.camera_optimizer;
        let n = self.model.n_cameras;
        pk.regularizer(rec, slot, (n, self.n_train_cameras), (co.trans_l2_penalty, co.rot_l2_penalty), &pb.reg_losses)?;
        Ok(n)
    }

    /// The chunk's pixels, cameras and targets (zeros when rendering) and, with depth supervision, its depth targets
    /// (none given: no ray has one), in one submission.
    fn upload_rays(
        &self,
        b: &ChunkBuffers<GpuAlloc>,
        pixels: &[u32],
        targets: Option<&[f32]>,
        depth: Option<&[f32]>,
    ) -> GpuResult<()> {
        let cams: Vec<u32> = pixels.chunks(3).map(|p| p[0]).collect();
        let zeros;
        let targets = match targets {
            Some(t) => t,
            None => {
                zeros = vec![0.0f32; cams.len() * (self.model.bands + 1)];
                &zeros
            }
        };
        let mut parts = vec![
            Part::upload(&b.pixels, 0, pixels)?,
            Part::upload(&b.cam_idx, 0, &cams)?,
            Part::upload(&b.targets, 0, targets)?,
        ];
        let none;
        if let Some(buf) = &b.depth_targets {
            let d = match depth {
                Some(d) if !d.is_empty() => d,
                _ => {
                    none = vec![0.0f32; 2 * cams.len()];
                    &none
                }
            };
            parts.push(Part::upload(buf, 0, d)?);
        }
        self.ctx.upload_parts(&parts)
    }

    /// Records one training step's work on `n_rays` rays whose inputs are in `io`: the guard's reset, zeroed
    /// gradients, then per chunk the input copies, forward, backward, the chunk's guard checks and its output
    /// copies; then the pose regulariser, the guard's end checks and the flag copy. Returns the number of pose
    /// regulariser losses copied out. Adam is recorded by the caller.
    #[allow(clippy::too_many_arguments)]
    fn record_step(
        &self,
        rec: &mut Recorder,
        b: &ChunkBuffers<GpuAlloc>,
        io: &StepIo,
        n_rays: usize,
        norms: (f32, f32, f32, f32),
        update_props: bool,
    ) -> GpuResult<usize> {
        let guard = self.guard.as_ref().expect("the guard is allocated with the training buffers");
        let l = io.layout;
        let bands = self.model.bands;
        let row = l.ray_out_row();
        guard.record_reset(rec)?;
        self.model.store.zero_grads(rec)?;
        let mut last = 0;
        for c0 in (0..n_rays).step_by(b.rays) {
            let r = b.rays.min(n_rays - c0);
            last = r;
            rec.copy_in(&io.input, l.pixels + 12 * c0 as u64, &b.pixels, 0, 3 * r)?;
            rec.copy_in(&io.input, l.cams + 4 * c0 as u64, &b.cam_idx, 0, r)?;
            rec.copy_in(&io.input, l.targets + 4 * (c0 * (bands + 1)) as u64, &b.targets, 0, r * (bands + 1))?;
            if let Some(d) = &b.depth_targets {
                rec.copy_in(&io.input, l.depth + 8 * c0 as u64, d, 0, 2 * r)?;
            }
            self.record_forward(rec, b, (r, c0), true, update_props)?;
            self.record_backward(rec, b, (r, c0), norms, update_props)?;
            guard.record_chunk(rec, b, r, update_props)?;
            rec.copy_out(&b.ray_out, 0, r * row, &io.output, l.ray_out + 4 * (c0 * row) as u64)?;
            if update_props {
                for (p, pl) in b.proposals.iter().enumerate() {
                    let at = l.interlevel + 4 * (p * l.rays + c0) as u64;
                    rec.copy_out(need(&pl.losses), 0, r, &io.output, at)?;
                }
            }
        }
        let n_reg = self.record_pose_regularizer(rec, b)?;
        guard.record_end(rec, b, last, &self.model.store, n_reg)?;
        rec.copy_out(&guard.flags, 0, guard.words(), &io.output, l.flags)?;
        if let Some(pb) = b.pose.as_ref().filter(|_| n_reg > 0) {
            rec.copy_out(&pb.reg_losses, 0, n_reg, &io.output, l.reg)?;
        }
        Ok(n_reg)
    }

    /// Runs every kernel of a training step (with and without a proposal update, the guard and the pose
    /// regulariser; the optimiser's pipelines are created) and of inference once, on one ray (pixel (0, 0) of the
    /// first camera), so that all pipelines are created and compiled before a training clock starts: lavapipe
    /// compiles each pipeline with LLVM at its first dispatch (a second or more for the unrolled MLP tiles).
    /// Parameters and optimiser state are untouched; the gradients it leaves are zeroed at the start of every step.
    /// Where the hash grids choose their kernels by the pass size (GPUs: one dispatch for all levels up to
    /// [`crate::nn::hashgrid::GPU_ONE_DISPATCH_MAX_POINTS`] points, one per level above), the one ray runs both ways.
    pub fn warm_up(&mut self) -> GpuResult<()> {
        let max = self.model.field.grid.one_dispatch_max_points();
        let both_ways = max > 0 && max < usize::MAX;
        self.warm_up_once()?;
        if both_ways {
            self.model.set_hash_one_dispatch_max(0);
            let res = self.warm_up_once();
            self.model.set_hash_one_dispatch_max(max);
            res?;
        }
        Ok(())
    }

    fn warm_up_once(&mut self) -> GpuResult<()> {
        let pixels = [0u32, 0, 0];
        self.render(&pixels)?;
        self.flush()?;
        self.ensure_buffers(true)?;
        self.ensure_io(0, 1)?;
        let targets = vec![0.0f32; self.model.bands + 1];
        self.io[0].write_batch(&pixels, &[0], &targets, &[])?;
        let b = self.train_bufs.take().expect("ensured above");
        let res = (|| {
            for update_props in [true, false] {
                let mut rec = self.ctx.recorder("warm-up")?;
                self.record_step(&mut rec, &b, &self.io[0], 1, (0.0, 0.0, 0.0, 0.0), update_props)?;
                rec.submit_and_wait()?;
            }
            crate::nn::adam::kernels(&self.ctx, true)?;
            Ok(())
        })();
        self.train_bufs = Some(b);
        res
    }

    /// One training step on `batch`, waited for (steps submitted earlier with [`Pipeline::submit_step`] finish
    /// first; their results are dropped: use [`Pipeline::flush`] before calling this when they matter).
    pub fn train_step(&mut self, batch: &Batch) -> Result<StepStats, GpuError> {
        self.flush()?;
        self.submit_step(batch)?;
        let mut done = self.flush()?;
        Ok(done.pop().expect("the step just submitted"))
    }

    /// Steps submitted and not yet collected.
    pub fn in_flight(&self) -> usize {
        self.pending.len()
    }

    /// Records and submits one training step on `batch` without waiting for it; waits first for the oldest step
    /// when `steps_in_flight` are already submitted. Collect results with [`Pipeline::completed`] or
    /// [`Pipeline::flush`].
    pub fn submit_step(&mut self, batch: &Batch) -> Result<(), GpuError> {
        self.ensure_buffers(true)?;
        let bands = self.model.bands;
        let n_rays = batch.rays();
        let cfg = &self.model.cfg;
        if cfg.loss.depth.is_some() && batch.depth.len() != 2 * n_rays {
            return Err(GpuError::Dispatch {
                kernel: "train step".into(),
                msg: format!(
                    "loss.depth is set but the batch has {} depth values for {n_rays} rays",
                    batch.depth.len()
                ),
            });
        }
        let ray_cameras = batch.ray_cameras();
        if let Some(&c) = ray_cameras.iter().find(|&&c| c as usize >= self.model.n_cameras) {
            return Err(GpuError::Dispatch {
                kernel: "train step".into(),
                msg: format!(
                    "a ray's camera {c} is not one of the model's {} cameras (per-camera parameters; a band \
                     camera's ray names its frame in Batch::cameras)",
                    self.model.n_cameras
                ),
            });
        }
        if !batch.cameras.is_empty() && batch.cameras.len() != n_rays {
            return Err(GpuError::Dispatch {
                kernel: "train step".into(),
                msg: format!("a batch of {n_rays} rays names the cameras of {} rays", batch.cameras.len()),
            });
        }
        if batch.pixels.len() != 3 * n_rays || batch.targets.len() != n_rays * (bands + 1) {
            return Err(GpuError::Dispatch {
                kernel: "train step".into(),
                msg: format!(
                    "a batch of {} pixel values has {} targets ({} bands + a weight per ray expected)",
                    batch.pixels.len(),
                    batch.targets.len(),
                    bands
                ),
            });
        }
        let total_w: f64 = (0..n_rays).map(|i| batch.ray_weight(i) as f64).sum();
        // Every target observed: `observed` is total_w * B, the per-band means of eq. 3.1 averaged over the bands.
        let observed = batch.observed_targets(bands).max(bands as f64);
        let norms = (
            (1.0 / observed) as f32,
            (cfg.loss.distortion_at(self.step) as f64 / total_w.max(1.0)) as f32,
            (cfg.loss.interlevel_mult as f64 / (n_rays.max(1) * cfg.sampling.num_nerf_samples) as f64) as f32,
            cfg.loss.depth.map_or(0.0, |d| (d.mult as f64 / total_w.max(1.0)) as f32),
        );
        // A change of `steps_in_flight` takes effect with an empty ring.
        if self.io.len() != self.steps_in_flight.clamp(1, 3) {
            self.flush_into_finished()?;
            self.steps_in_flight = self.steps_in_flight.clamp(1, 3);
            self.io.clear();
            self.next_io = 0;
        }
        while self.pending.len() >= self.steps_in_flight {
            self.harvest_oldest()?;
        }
        let slot = self.next_io;
        self.ensure_io(slot, n_rays)?;
        self.io[slot].write_batch(&batch.pixels, &ray_cameras, &batch.targets, &batch.depth)?;
        let update_props =
            self.schedule.decide(&self.model.cfg.sampling, self.step) && !self.model.proposals.is_empty();
        let profiled = self.profile_every > 0 && self.step % self.profile_every == 0;
        let store = &self.model.store;
        let lr_fields =
            store.groups().iter().position(|g| g.name == super::model::FIELDS_GROUP).map_or(0.0, |g| store.lr(g));
        let stats =
            StepStats { step: self.step, proposals_updated: update_props, profiled, lr_fields, ..Default::default() };
        let b = self.train_bufs.take().expect("ensured above");
        // Everything fallible runs in here, so an error never leaves `train_bufs` taken (the next step would
        // otherwise allocate them again without a word).
        let ctx = self.ctx.clone();
        let recorded = (|| {
            let mut rec = ctx.recorder_timed("train step", profiled)?;
            let n_reg = self.record_step(&mut rec, &b, &self.io[slot], n_rays, norms, update_props)?;
            Ok((rec, n_reg))
        })();
        self.train_bufs = Some(b);
        let (mut rec, n_reg) = recorded?;
        // Fields and camera corrections get gradients every step, the proposals on update steps.
        let has_grad: Vec<bool> =
            self.model.store.groups().iter().map(|g| g.name != "proposals" || update_props).collect();
        let gate = &self.guard.as_ref().expect("allocated with the training buffers").flags;
        let adam = crate::nn::adam::step_gated(&mut rec, &mut self.model.store, &has_grad, 1.0, Some(gate))?;
        let flight = match rec.submit() {
            Ok(f) => f,
            Err(e) => {
                self.model.store.undo_step(&adam);
                return Err(e);
            }
        };
        self.pending.push_back(PendingStep { io: slot, flight, stats, n_rays, observed, n_reg, adam });
        self.next_io = (slot + 1) % self.steps_in_flight;
        self.step += 1;
        Ok(())
    }

    /// The results of every submitted step the device has finished, oldest first (never blocks).
    pub fn completed(&mut self) -> GpuResult<Vec<StepStats>> {
        while let Some(p) = self.pending.front() {
            if !p.flight.is_done()? {
                break;
            }
            self.harvest_oldest()?;
        }
        Ok(self.finished.drain(..).collect())
    }

    /// Waits for every submitted step; returns the results not collected yet, oldest first.
    pub fn flush(&mut self) -> GpuResult<Vec<StepStats>> {
        self.flush_into_finished()?;
        Ok(self.finished.drain(..).collect())
    }

    fn flush_into_finished(&mut self) -> GpuResult<()> {
        while !self.pending.is_empty() {
            self.harvest_oldest()?;
        }
        Ok(())
    }

    /// Waits for the oldest submitted step and reads its losses and guard flags.
    fn harvest_oldest(&mut self) -> GpuResult<()> {
        let Some(p) = self.pending.pop_front() else { return Ok(()) };
        let mut stats = p.stats;
        stats.timing = p.flight.wait()?;
        let io = &self.io[p.io];
        let l = io.layout;
        let out: Vec<f32> = io.output.read(l.ray_out, p.n_rays * l.ray_out_row())?;
        let mut sq = 0.0f64;
        for row in out.chunks(l.ray_out_row()) {
            stats.loss_rgb += RayOut::LossRgb.of(row) as f64;
            stats.loss_distortion += RayOut::LossDistortion.of(row) as f64;
            sq += RayOut::SquaredError.of(row) as f64;
            stats.loss_depth += RayOut::LossDepth.of(row) as f64;
        }
        if stats.proposals_updated {
            for q in 0..l.proposals {
                let v: Vec<f32> = io.output.read(l.interlevel + 4 * (q * l.rays) as u64, p.n_rays)?;
                stats.loss_interlevel += v.iter().map(|&x| x as f64).sum::<f64>();
            }
        }
        if p.n_reg > 0 {
            let v: Vec<f32> = io.output.read(l.reg, p.n_reg)?;
            stats.loss_pose = v.iter().map(|&x| x as f64).sum();
        }
        let guard = self.guard.as_ref().expect("allocated with the training buffers");
        let words: Vec<u32> = io.output.read(l.flags, guard.words())?;
        stats.poisoned = guard.first_named(&words);
        let finite = [stats.loss_rgb, stats.loss_distortion, stats.loss_interlevel, stats.loss_depth, stats.loss_pose]
            .iter()
            .all(|x| x.is_finite());
        if stats.poisoned.is_none() && !finite {
            // Every loss buffer is checked on the device, so this cannot happen; say so if it does.
            stats.poisoned = Some("ray outputs (non-finite loss sum; the device saw none)".into());
        }
        if stats.poisoned.is_some() {
            stats.skipped = true;
            self.model.store.undo_step(&p.adam);
        }
        stats.loss =
            stats.loss_rgb + stats.loss_distortion + stats.loss_interlevel + stats.loss_depth + stats.loss_pose;
        stats.psnr = -10.0 * (sq / p.observed).max(1e-20).log10();
        self.finished.push_back(stats);
        Ok(())
    }

    /// Renders rays (pixels as (camera, row, col) triples) in evaluation mode.
    pub fn render(&mut self, pixels: &[u32]) -> GpuResult<RenderOut> {
        self.ensure_buffers(false)?;
        let bands = self.model.bands;
        let n = pixels.len() / 3;
        let b = self.eval_bufs.take().expect("ensured above");
        let mut out = RenderOut::default();
        let res = (|| {
            self.update_mean_appearance()?;
            for c0 in (0..n).step_by(b.rays) {
                let r = b.rays.min(n - c0);
                self.upload_rays(&b, &pixels[3 * c0..3 * (c0 + r)], None, None)?;
                let mut rec = self.ctx.recorder("render chunk")?;
                self.record_forward(&mut rec, &b, (r, c0), false, false)?;
                let geo = self.geometry(true);
                let rb = RayBuffers { origins: &b.origins, dirs: &b.dirs, n_rays: r, ray_offset: 0 };
                let m = &self.model;
                let p = CompositeParams {
                    bands,
                    density_stride: m.field.mlp.config.n_output,
                    density_scale: m.cfg.field.average_init_density,
                    background: self.background(false),
                    rgb_norm: 0.0,
                    dist_norm: 0.0,
                    train: false,
                    grad_scaling: false,
                    depth: None,
                };
                let cb = CompositeBuffers {
                    edges: &b.nerf.edges,
                    density: &b.nerf.raw,
                    colours: &b.colour.out,
                    targets: &b.targets,
                    band_weights: &b.band_weights,
                    dy_density: &b.dummy,
                    dy_colour: &b.dummy,
                    weights: &b.nerf.weights,
                    ray_out: &b.ray_out,
                    depth_targets: None,
                };
                self.kernels.composite(&mut rec, rb, geo, b.nerf.n, &p, &cb)?;
                out.timing.accumulate(&rec.submit_and_wait()?);
                let got = self.ctx.download_parts(&[
                    Part::download(&b.ray_out, 0, r * (RAY_OUT_FIXED + bands))?,
                    Part::download(&b.norms, 0, r)?,
                ])?;
                let ro: Vec<f32> = bytemuck::pod_collect_to_vec(&got[0]);
                for row in ro.chunks(RAY_OUT_FIXED + bands) {
                    out.accumulation.push(RayOut::Accumulation.of(row));
                    out.median_depth.push(RayOut::MedianDepth.of(row));
                    out.expected_depth.push(RayOut::ExpectedDepth.of(row));
                    out.depth_q25.push(RayOut::DepthQ25.of(row));
                    out.depth_q75.push(RayOut::DepthQ75.of(row));
                    out.colour.extend_from_slice(&row[RAY_OUT_FIXED..]);
                }
                out.direction_norm.extend(bytemuck::pod_collect_to_vec::<u8, f32>(&got[1]));
            }
            GpuResult::Ok(())
        })();
        self.eval_bufs = Some(b);
        res.map(|_| out)
    }

    /// Evaluation uses the mean appearance embedding (nerfstudio's use_average_appearance_embedding) over the
    /// training cameras' rows ([`Pipeline::appearance_rows`]): it is stored in the spare last row of the slot.
    fn update_mean_appearance(&self) -> GpuResult<()> {
        let dim = self.model.cfg.field.appearance_embed_dim;
        if dim == 0 {
            return Ok(());
        }
        let store = &self.model.store;
        let slot = self.model.slots.appearance.clone().expect("appearance slot");
        let mut emb = store.download_slot(store.params(), &slot)?;
        let rows = self.model.n_cameras;
        let all: Vec<usize> = (0..rows).collect();
        let used: &[usize] = match &self.appearance_rows {
            Some(r) if !r.is_empty() => r,
            _ => &all,
        };
        let mean: Vec<f32> = (0..dim)
            .map(|k| {
                let sum: f64 = used.iter().filter(|&&r| r < rows).map(|&r| emb[r * dim + k] as f64).sum();
                (sum / used.len().max(1) as f64) as f32
            })
            .collect();
        emb[rows * dim..(rows + 1) * dim].copy_from_slice(&mean);
        store.upload_slot(store.params(), &slot, &emb)
    }
}
