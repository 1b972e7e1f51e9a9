//! The GPU buffers one chunk of rays needs, written once and generic over an allocator: [`GpuAlloc`] creates them,
//! [`PlanAlloc`] only records (name, category, bytes). The VRAM planner uses the second, so it cannot drift from what
//! the trainer allocates.

use super::model::{Model, ModelShapes};
use crate::gpu::{BufferDesc, Context, GpuBuffer, GpuResult, MemoryCategory};

/// Something that hands out buffers of f32 and u32 elements.
pub trait Alloc {
    type F;
    type U;
    fn f32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<Self::F>;
    fn u32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<Self::U>;
}

/// Allocates real buffers on a context.
pub struct GpuAlloc(pub Context);

impl Alloc for GpuAlloc {
    type F = GpuBuffer<f32>;
    type U = GpuBuffer<u32>;
    fn f32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<GpuBuffer<f32>> {
        GpuBuffer::new(&self.0, &BufferDesc { name, len, category })
    }
    fn u32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<GpuBuffer<u32>> {
        GpuBuffer::new(&self.0, &BufferDesc { name, len, category })
    }
}

/// One planned buffer.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PlannedBuffer {
    pub name: String,
    pub category: MemoryCategory,
    pub bytes: u64,
}

#[derive(Default)]
pub struct PlanAlloc {
    pub buffers: Vec<PlannedBuffer>,
}

impl Alloc for PlanAlloc {
    type F = ();
    type U = ();
    fn f32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<()> {
        self.buffers.push(PlannedBuffer { name: name.into(), category, bytes: (len * 4) as u64 });
        Ok(())
    }
    fn u32(&mut self, name: &str, category: MemoryCategory, len: usize) -> GpuResult<()> {
        self.f32(name, category, len)
    }
}

/// Per sampling level (a proposal, or the NeRF density part).
pub struct LevelBuffers<A: Alloc> {
    pub n: usize,
    pub edges: A::F,
    pub positions: A::F,
    /// Hash encoding rows = the density MLP's input (stride in_pad).
    pub enc: A::F,
    /// Density MLP output rows: raw density (+ geometric features for the NeRF field).
    pub raw: A::F,
    pub weights: A::F,
    /// Training only: the density MLP's backward buffers (dy = dL/draw rows, dx = dL/denc rows).
    pub train: Option<Backward<A>>,
    /// Interlevel loss per ray (training, proposal levels only).
    pub losses: Option<A::F>,
}

/// The training-only buffers of one MLP's backward pass, present together or not at all.
pub struct Backward<A: Alloc> {
    /// Hidden-layer activations kept from the forward pass.
    pub acts: A::F,
    pub deltas: A::F,
    /// Split-K weight-gradient scratch.
    pub scratch: A::F,
    /// dL/d(output) rows.
    pub dy: A::F,
    /// dL/d(input) rows.
    pub dx: A::F,
}

/// The colour head's buffers (NeRF level).
pub struct ColourBuffers<A: Alloc> {
    pub input: A::F,
    pub out: A::F,
    /// Training only: dy = dL/dc rows, dx = dL/dinput rows.
    pub train: Option<Backward<A>>,
}

/// Camera pose refinement (training with the camera optimiser on): the uncorrected ray directions, the hash-input
/// gradient of one level at a time, each ray's (dL/dorigin, dL/ddirection) and the regulariser's per-camera loss.
pub struct PoseBuffers<A: Alloc> {
    pub raw_dirs: A::F,
    pub dpos: A::F,
    pub ray_grads: A::F,
    pub reg_losses: A::F,
}

pub struct ChunkBuffers<A: Alloc> {
    pub rays: usize,
    pub pixels: A::U,
    pub cam_idx: A::U,
    pub origins: A::F,
    pub dirs: A::F,
    pub norms: A::F,
    /// B values and the ray weight per ray.
    pub targets: A::F,
    pub ray_out: A::F,
    pub band_weights: A::F,
    pub proposals: Vec<LevelBuffers<A>>,
    pub nerf: LevelBuffers<A>,
    pub colour: ColourBuffers<A>,
    pub pose: Option<PoseBuffers<A>>,
    /// Inference only: the hidden-layer scratch every MLP runs through (training uses each MLP's activations).
    pub mlp_scratch: Option<A::F>,
    /// Bound where a kernel's optional input is absent (e.g. no appearance embedding).
    pub dummy: A::F,
    /// Training with `loss.depth`: per ray (target distance, sigma); absent otherwise (free when off).
    pub depth_targets: Option<A::F>,
}

/// The per-ray output columns of the composite kernel before the B colours, as named in
/// `glsl/render/ray_out.glsl` (a unit test below compares the two lists).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum RayOut {
    /// Band-weighted colour loss (times its normaliser and the ray weight).
    LossRgb,
    /// Distortion loss (times its normaliser and the ray weight).
    LossDistortion,
    /// Accumulated opacity A.
    Accumulation,
    /// Exact crossing of A = 0.5.
    MedianDepth,
    /// Weighted mean depth.
    ExpectedDepth,
    /// Unweighted squared error summed over bands (times the ray weight).
    SquaredError,
    /// Crossing of 0.25 A.
    DepthQ25,
    /// Crossing of 0.75 A.
    DepthQ75,
    /// Depth loss (times its normaliser and the ray weight).
    LossDepth,
}

impl RayOut {
    /// Every fixed column, in buffer order.
    pub const ALL: [RayOut; 9] = [
        RayOut::LossRgb,
        RayOut::LossDistortion,
        RayOut::Accumulation,
        RayOut::MedianDepth,
        RayOut::ExpectedDepth,
        RayOut::SquaredError,
        RayOut::DepthQ25,
        RayOut::DepthQ75,
        RayOut::LossDepth,
    ];

    /// The column's index in a ray's row.
    pub const fn col(self) -> usize {
        self as usize
    }

    /// This column of one ray's row (`RAY_OUT_FIXED + B` floats).
    pub fn of(self, row: &[f32]) -> f32 {
        row[self as usize]
    }

    /// The GLSL constant naming the column.
    pub const fn glsl_name(self) -> &'static str {
        match self {
            RayOut::LossRgb => "RO_LOSS_RGB",
            RayOut::LossDistortion => "RO_LOSS_DISTORTION",
            RayOut::Accumulation => "RO_ACCUMULATION",
            RayOut::MedianDepth => "RO_MEDIAN_DEPTH",
            RayOut::ExpectedDepth => "RO_EXPECTED_DEPTH",
            RayOut::SquaredError => "RO_SQUARED_ERROR",
            RayOut::DepthQ25 => "RO_DEPTH_Q25",
            RayOut::DepthQ75 => "RO_DEPTH_Q75",
            RayOut::LossDepth => "RO_LOSS_DEPTH",
        }
    }
}

/// Per-ray output columns of the composite kernel besides the B colours (the colours start here).
pub const RAY_OUT_FIXED: usize = RayOut::ALL.len();

/// An MLP's activations, deltas and weight-gradient scratch (None for inference); allocated before the level's
/// other buffers, [`Backward::finish`] adds dy and dx after them (the ledger's order).
type MlpTrain<A> = Option<[<A as Alloc>::F; 3]>;

fn mlp_train<A: Alloc>(
    a: &mut A,
    name: &str,
    mlp: &crate::nn::mlp::MlpConfig,
    rows: usize,
    train: bool,
) -> GpuResult<MlpTrain<A>> {
    if !train {
        return Ok(None);
    }
    let act = MemoryCategory::Activations;
    Ok(Some([
        a.f32(&format!("{name} activations"), act, mlp.hidden_floats(rows))?,
        a.f32(&format!("{name} deltas"), act, mlp.delta_floats(rows))?,
        a.f32(&format!("{name} weight-gradient scratch"), act, mlp.wgrad_scratch_floats(rows))?,
    ]))
}

impl<A: Alloc> Backward<A> {
    /// The MLP buffers of [`mlp_train`] plus dy (`dy_name`, `dy_floats`) and dx; None for inference.
    fn finish(a: &mut A, mlp: MlpTrain<A>, dy: (&str, usize), dx: (&str, usize)) -> GpuResult<Option<Self>> {
        let Some([acts, deltas, scratch]) = mlp else { return Ok(None) };
        let act = MemoryCategory::Activations;
        let dy = a.f32(dy.0, act, dy.1)?;
        let dx = a.f32(dx.0, act, dx.1)?;
        Ok(Some(Backward { acts, deltas, scratch, dy, dx }))
    }
}

impl<A: Alloc> ChunkBuffers<A> {
    /// Buffers for `rays` rays of `model`; `train` adds what the backward pass needs.
    pub fn new(a: &mut A, model: &Model, rays: usize, train: bool) -> GpuResult<Self> {
        Self::with_shapes(a, &model.shapes(), rays, train)
    }

    /// The same from the configuration alone (what the VRAM planner calls with [`PlanAlloc`]).
    pub fn with_shapes(a: &mut A, model: &ModelShapes, rays: usize, train: bool) -> GpuResult<Self> {
        let (act, ray) = (MemoryCategory::Activations, MemoryCategory::Rays);
        let bands = model.bands;
        let cfg = &model.cfg;
        let level = |a: &mut A,
                     name: &str,
                     n: usize,
                     enc_w: usize,
                     raw_w: usize,
                     mlp: &crate::nn::mlp::MlpConfig,
                     prop: bool| {
            let s = rays * n;
            let mlp_bufs = mlp_train(a, &format!("{name} MLP"), mlp, s, train)?;
            GpuResult::Ok(LevelBuffers {
                n,
                edges: a.f32(&format!("{name} edges"), act, rays * (n + 1))?,
                positions: a.f32(&format!("{name} positions"), act, s * 3)?,
                enc: a.f32(&format!("{name} encoding"), act, s * enc_w)?,
                raw: a.f32(&format!("{name} density"), act, s * raw_w)?,
                weights: a.f32(&format!("{name} weights"), act, s)?,
                train: Backward::finish(
                    a,
                    mlp_bufs,
                    (&format!("{name} dL/ddensity"), s * raw_w),
                    (&format!("{name} dL/dencoding"), s * enc_w),
                )?,
                losses: if train && prop {
                    Some(a.f32(&format!("{name} interlevel losses"), ray, rays)?)
                } else {
                    None
                },
            })
        };
        let mut proposals = Vec::new();
        for (i, (m, pc)) in model.proposal_mlps.iter().zip(&cfg.proposals).enumerate() {
            proposals.push(level(a, &format!("proposal {i}"), pc.samples, m.in_pad(), m.n_output, m, true)?);
        }
        let fm = &model.field_mlp;
        let n = cfg.sampling.num_nerf_samples;
        let nerf = level(a, "nerf", n, fm.in_pad(), fm.n_output, fm, false)?;
        let cm = &model.colour_mlp;
        let s = rays * n;
        let mlp_bufs = mlp_train(a, "colour MLP", cm, s, train)?;
        let colour = ColourBuffers {
            input: a.f32("colour input", act, s * cm.in_pad())?,
            out: a.f32("colour output", act, s * bands)?,
            train: Backward::finish(a, mlp_bufs, ("colour dL/dc", s * bands), ("colour dL/dinput", s * cm.in_pad()))?,
        };
        let pose = if train && cfg.camera_optimizer.enabled() {
            let most = cfg.proposals.iter().map(|p| p.samples).chain([n]).max().unwrap_or(n);
            Some(PoseBuffers {
                raw_dirs: a.f32("uncorrected ray directions", ray, rays * 3)?,
                dpos: a.f32("pose dL/dposition", act, rays * most * 3)?,
                ray_grads: a.f32("pose dL/dray", ray, rays * 6)?,
                reg_losses: a.f32("pose regulariser losses", MemoryCategory::Other, model.n_cameras.max(1))?,
            })
        } else {
            None
        };
        let mlp_scratch = if train {
            None
        } else {
            let most = (model.proposal_mlps.iter().zip(&cfg.proposals))
                .map(|(m, p)| m.infer_scratch_floats(rays * p.samples))
                .chain([fm.infer_scratch_floats(s), cm.infer_scratch_floats(s)])
                .max()
                .unwrap_or(0);
            Some(a.f32("MLP inference scratch", act, most)?)
        };
        Ok(Self {
            rays,
            pixels: a.u32("ray pixels", ray, rays * 3)?,
            cam_idx: a.u32("ray cameras", ray, rays)?,
            origins: a.f32("ray origins", ray, rays * 3)?,
            dirs: a.f32("ray directions", ray, rays * 3)?,
            norms: a.f32("ray direction norms", ray, rays)?,
            targets: a.f32("ray targets", ray, rays * (bands + 1))?,
            ray_out: a.f32("ray outputs", ray, rays * (RAY_OUT_FIXED + bands))?,
            band_weights: a.f32("band weights", MemoryCategory::Other, bands)?,
            proposals,
            nerf,
            colour,
            pose,
            mlp_scratch,
            dummy: a.f32("dummy binding", MemoryCategory::Other, 4)?,
            depth_targets: if train && cfg.loss.depth.is_some() {
                Some(a.f32("ray depth targets", ray, rays * 2)?)
            } else {
                None
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::{RayOut, RAY_OUT_FIXED};

    /// `glsl/render/ray_out.glsl`'s `const uint NAME = Nu;` lines are the Rust enum's names and indices, in order,
    /// and RAY_OUT_FIXED agrees: a column added on one side only, or two swapped, fails here.
    #[test]
    fn ray_out_columns_match_the_glsl_include() {
        let text = include_str!("../../glsl/render/ray_out.glsl");
        let consts: Vec<(String, usize)> = text
            .lines()
            .filter_map(|l| l.trim().strip_prefix("const uint "))
            .map(|l| {
                let (name, rest) = l.split_once('=').expect("NAME = value");
                let value = rest.trim().split(|c: char| !c.is_ascii_digit()).next().expect("a number");
                (name.trim().to_owned(), value.parse().expect("an integer"))
            })
            .collect();
        let mut want: Vec<(String, usize)> = RayOut::ALL.iter().map(|c| (c.glsl_name().to_owned(), c.col())).collect();
        want.push(("RAY_OUT_FIXED".to_owned(), RAY_OUT_FIXED));
        assert_eq!(consts, want);
    }
}
