//! Model configuration (`configs/models/*.yaml`): nerfacto's defaults (spec/nerfacto.md §1) as one profile,
//! Multispectral-NeRF's Table 1 as another, and small ones for CI. Unknown keys are errors that name the key
//! (`deny_unknown_fields`). The number of bands is not here: it comes from the dataset.

pub use super::config_error::ConfigError;
use crate::nn::hashgrid::HashGridConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    pub name: String,
    pub field: FieldConfig,
    /// One entry per proposal level, coarse to fine.
    pub proposals: Vec<ProposalConfig>,
    pub sampling: SamplingConfig,
    #[serde(default)]
    pub rendering: RenderingConfig,
    #[serde(default)]
    pub loss: LossConfig,
    pub optimizer: OptimizerConfig,
    /// Camera pose refinement (off unless asked for; then one 6-vector per camera in its own optimiser group).
    #[serde(default)]
    pub camera_optimizer: CameraOptimizerConfig,
    pub trainer: TrainerConfig,
    /// How the MLPs store their hidden activations between the forward and the backward pass: `f32` (default) or
    /// `f16` (half the memory of the largest training buffers; sums stay fp32; tiny-cuda-nn keeps them in fp16).
    #[serde(default)]
    pub mlp_activations: ActivationStorage,
}

/// Storage type of the MLPs' hidden activations.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ActivationStorage {
    #[default]
    F32,
    F16,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldConfig {
    pub grid: HashGridConfig,
    /// Density MLP: hidden width and number of linear layers (tcnn n_hidden_layers = num_layers - 1).
    pub hidden_dim: usize,
    pub num_layers: usize,
    /// Geometric features passed from the density MLP to the colour MLP.
    pub geo_feat_dim: usize,
    pub hidden_dim_color: usize,
    pub num_layers_color: usize,
    /// Per-image appearance embedding width; 0 turns the module off (no memory, no dispatch).
    #[serde(default)]
    pub appearance_embed_dim: usize,
    /// Spherical-harmonics degree of the view direction fed to the colour MLP, in tiny-cuda-nn's convention
    /// (degree d: d^2 values; nerfacto's 4 gives 16). Lower degrees zero the higher bands' columns, so the colour
    /// varies less with the view; 1 makes it view-independent (Lambertian).
    #[serde(default = "default_sh_degree", skip_serializing_if = "is_default_sh_degree")]
    pub direction_sh_degree: usize,
    /// Coarse-to-fine hash-grid levels (off when absent): the field's grid starts with `levels` levels and adds the
    /// others linearly until `until_step` ([`FieldConfig::active_levels_at`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coarse_to_fine: Option<CoarseToFine>,
    /// sigma = average_init_density * exp(raw).
    pub average_init_density: f32,
}

/// `field.coarse_to_fine`: the NeRF field's hash grid starts with its `levels` coarsest levels; the finer ones
/// fade in linearly until `until_step` (level l's features and gradients are weighted clamp(active - l, 0, 1), with
/// active = levels + (L - levels) * min(step / until_step, 1)), as BARF (Lin et al. 2021) and Neuralangelo (Li et
/// al. 2023) do, so that the geometry settles at coarse scales before fine levels can fit texture with bumps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoarseToFine {
    pub levels: u32,
    pub until_step: u64,
}

fn default_sh_degree() -> usize {
    4
}

fn is_default_sh_degree(d: &usize) -> bool {
    *d == default_sh_degree()
}

impl FieldConfig {
    /// SH values the colour MLP sees (the rest of its 16 direction columns are zero).
    pub fn sh_count(&self) -> usize {
        self.direction_sh_degree * self.direction_sh_degree
    }

    /// The field grid's active levels at `step` (`HashGrid::set_active_levels`): all of them without
    /// `coarse_to_fine`.
    pub fn active_levels_at(&self, step: u64) -> f32 {
        let all = self.grid.n_levels as f64;
        match &self.coarse_to_fine {
            None => all as f32,
            Some(c) => {
                let t = (step as f64 / c.until_step.max(1) as f64).min(1.0);
                (c.levels as f64 + (all - c.levels as f64) * t) as f32
            }
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProposalConfig {
    pub grid: HashGridConfig,
    pub hidden_dim: usize,
    pub num_layers: usize,
    /// Samples this level draws (256 and 96 in nerfacto).
    pub samples: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingConfig {
    pub num_nerf_samples: usize,
    pub near: f32,
    pub far: f32,
    #[serde(default = "yes")]
    pub scene_contraction: bool,
    #[serde(default = "yes")]
    pub single_jitter: bool,
    pub proposal_update_every: u64,
    pub proposal_warmup: u64,
    #[serde(default = "yes")]
    pub use_proposal_weight_anneal: bool,
    pub proposal_weights_anneal_slope: f64,
    pub proposal_weights_anneal_max_num_iters: u64,
    /// How poses are normalised: `poses` (nerfstudio's, the default), `aerial` (the cube fitted to the ground the
    /// cameras see, `data::aerial`) or `auto` (aerial when the cameras look down and their axes meet).
    #[serde(default)]
    pub pose_normalization: crate::data::PoseNormalization,
    /// Leave frames whose camera centre lies far outside the others out of the run (listed in the log and the
    /// run's dataset.json) instead of refusing the dataset (`data::outliers`; `msnerf train --drop-outliers`).
    #[serde(default)]
    pub drop_outlier_cameras: bool,
    /// Trace each band's rays from its own camera when the dataset has `rig_cameras` (rig-aware training,
    /// docs/dataset.md); `false` treats the bands as seen by the frame camera, as if they were registered
    /// (`msnerf train --no-rig-cameras`).
    #[serde(default = "yes")]
    pub rig_cameras: bool,
}

fn yes() -> bool {
    true
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Background {
    #[default]
    LastSample,
    Black,
    White,
    /// A random colour per ray and band in training (black in evaluation), as nerfstudio's `random`.
    Random,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct RenderingConfig {
    #[serde(default)]
    pub background: Background,
    /// Train the first this many steps with the `random` background, then with `background` (0, the default: off).
    /// A warm-up that makes leftover transmittance cost loss while the field forms, so the field turns opaque at the
    /// surface instead of leaving the `last_sample` colour to paint it from behind (docs/geometry.md, "A transparent
    /// field"); evaluation always uses `background`.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub random_background_steps: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

impl Background {
    /// What the ground truth of an image with alpha is composited over under this background, in training or in
    /// evaluation ([`crate::data::AlphaBackground`]).
    pub fn alpha_background(self, training: bool) -> crate::data::AlphaBackground {
        use crate::data::AlphaBackground;
        match self {
            Background::LastSample | Background::Black => AlphaBackground::Black,
            Background::White => AlphaBackground::White,
            Background::Random if training => AlphaBackground::Refuse,
            Background::Random => AlphaBackground::Black,
        }
    }
}

impl RenderingConfig {
    /// [`Background::alpha_background`] for the whole section: training with a `random` warm-up
    /// (`random_background_steps`) refuses alpha as `random` does, since its first steps blend with random colours.
    pub fn alpha_background(&self, training: bool) -> crate::data::AlphaBackground {
        self.background_at(0, training).alpha_background(training)
    }

    /// The background of a training step (`train`) or of evaluation: `random` during the warm-up of
    /// [`RenderingConfig::random_background_steps`], `background` otherwise.
    pub fn background_at(&self, step: u64, train: bool) -> Background {
        if train && step < self.random_background_steps {
            Background::Random
        } else {
            self.background
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    pub interlevel_mult: f32,
    pub distortion_mult: f32,
    /// Optional weight per band in the MSE of eq. 3.1 (one per dataset band).
    #[serde(default)]
    pub band_weights: Option<Vec<f32>>,
    /// nerfacto's `use_gradient_scaling` (off by default): every NeRF-field output gradient is multiplied by
    /// clamp(t^2, 0, 1), damping near-camera floaters. Off costs nothing.
    #[serde(default)]
    pub gradient_scaling: bool,
    /// Optional distortion-loss schedule (off by default: `distortion_mult` throughout): the weight goes linearly
    /// from `distortion_mult` at step `from_step` to `mult` at step `to_step` and stays there. Concentrates the
    /// weights on one surface once the field has found it (docs/geometry.md); from the first step it collapses it.
    #[serde(default)]
    pub distortion_ramp: Option<DistortionRamp>,
    /// Optional depth supervision (off by default; free when off): docs/geometry.md "Depth supervision".
    #[serde(default)]
    pub depth: Option<DepthSupervision>,
}

/// The depth loss of [`DepthSupervision`], as in nerfstudio's depth-nerfacto.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthLoss {
    /// Deng et al. 2022: -log of the weights under a Gaussian around the target.
    DsNerf,
    /// Rematas et al. 2022 (Urban Radiance Fields): expected-depth error, a Gaussian window of weights around the
    /// target and empty space (line of sight) in front of it.
    Urf,
}

/// Where depth targets come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthSource {
    /// The dataset's sparse 3-D points (`sparse_points_path`: SfM tracks, or the simulator's), projected into the
    /// training views that observed them.
    SparsePoints,
    /// The frames' depth maps (`depth_file_path`; nerfstudio's convention: 0 = no depth at that pixel).
    DepthMaps,
}

/// When `loss.depth` applies.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthWhen {
    /// Always: a dataset without the source is refused by name.
    #[default]
    Always,
    /// When the dataset has the source (sparse points from `msnerf sfm` or `import poses`, or depth maps); a dataset
    /// without it trains on the images alone, and the run says so. The profiles' default.
    Available,
}

/// `loss.depth`: depth supervision of the NeRF-level weights.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthSupervision {
    pub loss: DepthLoss,
    pub source: DepthSource,
    /// `always` (default) or `available`: see [`DepthWhen`].
    #[serde(default)]
    pub when: DepthWhen,
    /// Loss weight (nerfstudio's `depth_loss_mult`, 1e-3).
    #[serde(default = "depth_mult")]
    pub mult: f32,
    /// Standard deviation of a target, in the dataset's world units (metres for a georeferenced flight). nerfstudio's
    /// `depth_sigma` enters its DS-NeRF loss as a variance: its 0.01 (scene units) is a sigma of 0.1 here.
    pub sigma: f64,
    /// Fraction of each batch drawn from pixels that have a depth target (0: uniform pixels only, as nerfstudio;
    /// sparse points cover a few pixels per view, so uniform batches rarely meet one).
    #[serde(default)]
    pub ray_fraction: f64,
}

fn depth_mult() -> f32 {
    1e-3
}

/// See [`LossConfig::distortion_ramp`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistortionRamp {
    pub from_step: u64,
    pub to_step: u64,
    pub mult: f32,
}

impl LossConfig {
    /// The distortion weight at `step`.
    pub fn distortion_at(&self, step: u64) -> f32 {
        match self.distortion_ramp {
            None => self.distortion_mult,
            Some(r) if step <= r.from_step => self.distortion_mult,
            Some(r) if step >= r.to_step => r.mult,
            Some(r) => {
                let f = (step - r.from_step) as f32 / (r.to_step - r.from_step) as f32;
                self.distortion_mult + f * (r.mult - self.distortion_mult)
            }
        }
    }
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            interlevel_mult: 1.0,
            distortion_mult: 0.002,
            band_weights: None,
            gradient_scaling: false,
            distortion_ramp: None,
            depth: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupConfig {
    pub lr: f64,
    pub lr_final: f64,
    pub max_steps: u64,
    #[serde(default = "eps")]
    pub eps: f64,
}

fn eps() -> f64 {
    1e-15
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    pub fields: GroupConfig,
    pub proposals: GroupConfig,
    /// What the `fields` and `proposals` schedules span (the camera optimiser keeps its own step schedule).
    #[serde(default, skip_serializing_if = "LrSchedule::is_steps")]
    pub schedule: LrSchedule,
}

/// The length of the field and proposal learning-rate schedules (`optimizer.schedule`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    /// nerfstudio's ExponentialDecay: lr0 to lr_final over each group's `max_steps` optimiser steps, then constant.
    #[default]
    Steps,
    /// The same decay stretched over the whole run, whatever its length: the fraction done is the larger of steps
    /// over the step budget (`trainer.max_steps` or `--max-steps`) and seconds over the time budget
    /// (`--time-budget`), so a 90 s and a 10-minute run both end at lr_final. The groups' `max_steps` are unused.
    /// A time-budgeted run's schedule then depends on the machine's speed, as its step count already does.
    Run,
}

impl LrSchedule {
    fn is_steps(&self) -> bool {
        *self == LrSchedule::Steps
    }
}

/// How camera poses are refined during training (nerfstudio's `camera_optimizer.mode`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Default)]
pub enum CameraOptMode {
    /// Poses are used as given: no parameters, no memory, no dispatch.
    #[default]
    #[serde(rename = "off")]
    Off,
    /// Per camera a translation t and an axis-angle w: origin + t, direction rotated by exp(w) (spec §2.4).
    SO3xR3,
}

/// nerfstudio's camera optimiser: mode, its Adam group (lr 1e-3 decaying to 1e-4 over 5000 steps, eps 1e-15) and the
/// regulariser weights (0.01 mean |t| + 0.001 mean |w|).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraOptimizerConfig {
    #[serde(default)]
    pub mode: CameraOptMode,
    #[serde(default = "cam_lr")]
    pub lr: f64,
    #[serde(default = "cam_lr_final")]
    pub lr_final: f64,
    #[serde(default = "cam_max_steps")]
    pub max_steps: u64,
    #[serde(default = "eps")]
    pub eps: f64,
    #[serde(default = "cam_trans_penalty")]
    pub trans_l2_penalty: f32,
    #[serde(default = "cam_rot_penalty")]
    pub rot_l2_penalty: f32,
}

fn cam_lr() -> f64 {
    1e-3
}
fn cam_lr_final() -> f64 {
    1e-4
}
fn cam_max_steps() -> u64 {
    5000
}
fn cam_trans_penalty() -> f32 {
    1e-2
}
fn cam_rot_penalty() -> f32 {
    1e-3
}

impl Default for CameraOptimizerConfig {
    fn default() -> Self {
        Self {
            mode: CameraOptMode::Off,
            lr: cam_lr(),
            lr_final: cam_lr_final(),
            max_steps: cam_max_steps(),
            eps: eps(),
            trans_l2_penalty: cam_trans_penalty(),
            rot_l2_penalty: cam_rot_penalty(),
        }
    }
}

impl CameraOptimizerConfig {
    pub fn enabled(&self) -> bool {
        self.mode != CameraOptMode::Off
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainerConfig {
    pub max_steps: u64,
    pub rays_per_batch: usize,
    /// Rays per GPU pass; a batch is processed in chunks of this many rays (gradients add up), which bounds
    /// activation memory independently of the batch size.
    pub rays_per_chunk: usize,
    pub eval_rays_per_chunk: usize,
    pub steps_per_eval: u64,
    pub steps_per_save: u64,
    pub seed: u64,
    /// Training steps submitted to the device before the host waits for the oldest (1: every step waits for its
    /// own result; 2, the default: the host samples and records the next step while the device runs this one; at
    /// most 3). Losses and the NaN guard's verdict arrive that many steps late; the guard still skips a poisoned
    /// step on the device, in the step's own submission (`nerf::guard`).
    #[serde(default = "default_steps_in_flight")]
    pub steps_in_flight: usize,
    /// Per-dispatch GPU timestamps on one training step in this many (0: never); the summary's GPU time and
    /// kernel breakdown average over those steps. Timestamps cost GPU time on NVIDIA and host time everywhere.
    #[serde(default = "default_profile_every")]
    pub profile_every: u64,
}

fn default_steps_in_flight() -> usize {
    2
}

fn default_profile_every() -> u64 {
    10
}

/// The batch/chunk rule, defined once: a training chunk never exceeds its batch (a batch smaller than the chunk is
/// processed as one chunk of that batch). The trainer's flags, the planner, the sweep and the benchmarks apply it
/// through here or [`TrainerConfig::set_rays_per_batch`].
pub fn chunk_within_batch(rays_per_chunk: usize, rays_per_batch: usize) -> usize {
    rays_per_chunk.min(rays_per_batch)
}

impl TrainerConfig {
    /// Sets the batch, keeping the chunk within it ([`chunk_within_batch`]).
    pub fn set_rays_per_batch(&mut self, rays: usize) {
        self.rays_per_batch = rays;
        self.rays_per_chunk = chunk_within_batch(self.rays_per_chunk, rays);
    }

    /// Sets the chunk, within the batch ([`chunk_within_batch`]).
    pub fn set_rays_per_chunk(&mut self, rays: usize) {
        self.rays_per_chunk = chunk_within_batch(rays, self.rays_per_batch);
    }
}

impl ModelConfig {
    /// Loads and validates a model file; errors name the file and, for YAML problems, the key and line.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ConfigError::Read { path: path.to_path_buf(), reason: e.to_string() })?;
        Self::parse_in(&text, path.parent()).map_err(|e| e.in_profile(path.display().to_string()))
    }

    /// A profile's YAML; an `extends:` file is looked for relative to the working folder.
    pub fn parse(text: &str) -> Result<Self, ConfigError> {
        Self::parse_in(text, None)
    }

    /// A profile's YAML from the folder `dir` (where its `extends:` file lies; `super::config_extends`).
    fn parse_in(text: &str, dir: Option<&Path>) -> Result<Self, ConfigError> {
        if let Some(key) = crate::util::yaml::first_non_finite(text) {
            return Err(ConfigError::key(format!("{key}: not a finite number")));
        }
        let c: ModelConfig = match super::config_extends::resolve_extends(text, dir)? {
            Some(v) => serde_yaml::from_value(v).map_err(|e| ConfigError::key(e.to_string()))?,
            None => serde_yaml::from_str(text).map_err(|e| ConfigError::key(e.to_string()))?,
        };
        c.validate()?;
        Ok(c)
    }

    /// The built-in profiles (name, YAML), the one list every caller uses.
    pub const BUILTIN: [(&'static str, &'static str); 4] = [
        ("nerfacto", include_str!("../../configs/models/nerfacto.yaml")),
        ("multispectral-nerf", include_str!("../../configs/models/multispectral-nerf.yaml")),
        ("tiny", include_str!("../../configs/models/tiny.yaml")),
        ("demo", include_str!("../../configs/models/demo.yaml")),
    ];

    /// Whether `name` is a built-in profile.
    pub fn is_builtin(name: &str) -> bool {
        Self::BUILTIN.iter().any(|(n, _)| *n == name)
    }

    /// A built-in profile by name (`nerfacto`, `multispectral-nerf`, `tiny`, `demo`), or a path to a YAML file; a
    /// name that is neither is refused with the built-in list.
    pub fn resolve(name_or_path: &str) -> Result<Self, ConfigError> {
        match Self::BUILTIN.iter().find(|(n, _)| *n == name_or_path) {
            Some((_, t)) => Self::parse(t).map_err(|e| e.in_profile(format!("built-in model {name_or_path}"))),
            None => {
                let p = Path::new(name_or_path);
                if !p.exists() && !name_or_path.contains(['/', '.']) {
                    let names: Vec<&str> = Self::BUILTIN.iter().map(|(n, _)| *n).collect();
                    return Err(ConfigError::Invalid {
                        profile: name_or_path.to_string(),
                        reason: format!("no such model profile (built-in: {}, or a YAML file)", names.join(", ")),
                    });
                }
                Self::load(p)
            }
        }
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        let f = &self.field;
        f.grid.validate().map_err(|e| ConfigError::key(format!("field.grid: {e}")))?;
        for (i, p) in self.proposals.iter().enumerate() {
            p.grid.validate().map_err(|e| ConfigError::key(format!("proposals[{i}].grid: {e}")))?;
            if p.samples == 0 || p.num_layers < 2 {
                return Err(ConfigError::key(format!("proposals[{i}]: samples must be > 0 and num_layers >= 2")));
            }
        }
        if f.num_layers < 2 || f.num_layers_color < 2 {
            return Err(ConfigError::key(
                "field.num_layers and field.num_layers_color must be >= 2 (tcnn needs a hidden layer)",
            ));
        }
        if f.geo_feat_dim == 0 || f.geo_feat_dim + 1 > 128 {
            return Err(ConfigError::key(format!("field.geo_feat_dim must be 1..=127, got {}", f.geo_feat_dim)));
        }
        if let Some(c) = &f.coarse_to_fine {
            if c.levels == 0 || c.levels > f.grid.n_levels || c.until_step == 0 {
                return Err(ConfigError::key(format!(
                    "field.coarse_to_fine: levels must be 1..={} (field.grid.n_levels) and until_step > 0, got {} and {}",
                    f.grid.n_levels, c.levels, c.until_step
                )));
            }
        }
        if !(1..=4).contains(&f.direction_sh_degree) {
            return Err(ConfigError::key(format!(
                "field.direction_sh_degree must be 1..=4 (d^2 of the 16 SH values), got {}",
                f.direction_sh_degree
            )));
        }
        let s = &self.sampling;
        if !(s.near >= 0.0 && s.far > s.near) {
            return Err(ConfigError::key(format!("sampling: need 0 <= near < far, got {} and {}", s.near, s.far)));
        }
        if s.num_nerf_samples == 0 {
            return Err(ConfigError::key("sampling.num_nerf_samples must be > 0"));
        }
        if self.rendering.random_background_steps > 0 && self.rendering.background == Background::Random {
            return Err(ConfigError::key(
                "rendering.random_background_steps: a random-background warm-up needs another rendering.background \
                 to follow it (it is `random` already)",
            ));
        }
        if let Some(r) = &self.loss.distortion_ramp {
            if r.to_step <= r.from_step || !(r.mult.is_finite() && r.mult >= 0.0) {
                return Err(ConfigError::key(format!(
                    "loss.distortion_ramp: need from_step < to_step and mult >= 0, got {} .. {} and {}",
                    r.from_step, r.to_step, r.mult
                )));
            }
        }
        if let Some(d) = &self.loss.depth {
            if !(d.mult.is_finite() && d.mult > 0.0) {
                return Err(ConfigError::key(format!("loss.depth.mult must be > 0, got {}", d.mult)));
            }
            if !(d.sigma.is_finite() && d.sigma > 0.0) {
                return Err(ConfigError::key(format!("loss.depth.sigma must be > 0 (world units), got {}", d.sigma)));
            }
            if !(0.0..=1.0).contains(&d.ray_fraction) {
                return Err(ConfigError::key(format!(
                    "loss.depth.ray_fraction must be in [0, 1], got {}",
                    d.ray_fraction
                )));
            }
        }
        if !(f.average_init_density.is_finite() && f.average_init_density > 0.0) {
            return Err(ConfigError::key(format!(
                "field.average_init_density must be a number > 0, got {}",
                f.average_init_density
            )));
        }
        let l = &self.loss;
        for (key, v) in [("loss.interlevel_mult", l.interlevel_mult), ("loss.distortion_mult", l.distortion_mult)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::key(format!("{key} must be a number >= 0, got {v}")));
            }
        }
        if let Some(w) = &l.band_weights {
            if let Some((i, v)) = w.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= 0.0)) {
                return Err(ConfigError::key(format!("loss.band_weights[{i}] must be a number >= 0, got {v}")));
            }
            if !w.iter().any(|v| *v > 0.0) {
                return Err(ConfigError::key("loss.band_weights: at least one band needs a weight > 0"));
            }
        }
        for (name, g) in [("fields", &self.optimizer.fields), ("proposals", &self.optimizer.proposals)] {
            if !(g.lr.is_finite() && g.lr > 0.0 && g.lr_final.is_finite() && g.lr_final >= 0.0) {
                return Err(ConfigError::key(format!(
                    "optimizer.{name}: lr must be > 0 and lr_final >= 0, got {} and {}",
                    g.lr, g.lr_final
                )));
            }
            if !(g.eps.is_finite() && g.eps > 0.0) {
                return Err(ConfigError::key(format!("optimizer.{name}.eps must be > 0, got {}", g.eps)));
            }
        }
        // The MLPs' shapes as the model builds them (one band: the band count comes with the dataset).
        let shapes = super::model::ModelShapes::new(self, 1, 1);
        for (i, m) in shapes.proposal_mlps.iter().enumerate() {
            m.validate().map_err(|e| ConfigError::key(format!("proposals[{i}] (hidden_dim, num_layers): {e}")))?;
        }
        shapes
            .field_mlp
            .validate()
            .map_err(|e| ConfigError::key(format!("field (density MLP: hidden_dim, num_layers, geo_feat_dim): {e}")))?;
        shapes.colour_mlp.validate().map_err(|e| {
            ConfigError::key(format!(
                "field (colour MLP: hidden_dim_color, num_layers_color, appearance_embed_dim, direction inputs): {e}"
            ))
        })?;
        let co = &self.camera_optimizer;
        if !(co.lr >= 0.0 && co.lr_final >= 0.0 && co.trans_l2_penalty >= 0.0 && co.rot_l2_penalty >= 0.0) {
            return Err(ConfigError::key("camera_optimizer: lr, lr_final and the penalties must be >= 0"));
        }
        let t = &self.trainer;
        if t.rays_per_batch == 0 || t.rays_per_chunk == 0 || t.eval_rays_per_chunk == 0 {
            return Err(ConfigError::key(
                "trainer: rays_per_batch, rays_per_chunk and eval_rays_per_chunk must be > 0",
            ));
        }
        if t.steps_per_eval == 0 || t.steps_per_save == 0 {
            return Err(ConfigError::key(format!(
                "trainer.steps_per_eval and trainer.steps_per_save must be >= 1, got {} and {}",
                t.steps_per_eval, t.steps_per_save
            )));
        }
        if !(1..=3).contains(&t.steps_in_flight) {
            return Err(ConfigError::key(format!(
                "trainer.steps_in_flight must be 1, 2 or 3, got {}",
                t.steps_in_flight
            )));
        }
        Ok(())
    }

    /// The band-weight vector for `bands` bands (ones unless configured); an error names a length mismatch.
    pub fn band_weights(&self, bands: usize) -> Result<Vec<f32>, ConfigError> {
        match &self.loss.band_weights {
            None => Ok(vec![1.0; bands]),
            Some(w) if w.len() == bands => Ok(w.clone()),
            Some(w) => Err(ConfigError::key(format!(
                "loss.band_weights has {} entries, the dataset has {bands} bands",
                w.len()
            ))),
        }
    }
}
