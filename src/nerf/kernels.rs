//! Rust side of the render kernels in `glsl/render/`: one push-constant struct and one recording function per kernel.
//! Buffers follow the layouts documented in each kernel's header; per-ray data is row-major (ray, sample).

pub use super::config::DepthLoss;
use crate::gpu::{Binding, Context, GpuBuffer, GpuError, GpuResult, Kernel, Recorder};
use crate::shaders;

/// Sampling geometry shared by the kernels.
#[derive(Copy, Clone, Debug)]
pub struct Geometry {
    pub near: f32,
    pub far: f32,
    pub contraction: bool,
}

/// The per-ray buffers every render kernel reads.
#[derive(Copy, Clone)]
pub struct RayBuffers<'a> {
    pub origins: &'a GpuBuffer<f32>,
    pub dirs: &'a GpuBuffer<f32>,
    pub n_rays: usize,
    /// Global index of the first ray (the random stream is keyed on it).
    pub ray_offset: u32,
}

crate::push_constants! {
    struct RayGenPush {
        n_rays: u32,
    }
}

crate::push_constants! {
    struct SampleInitialPush {
        n_rays: u32,
        n: u32,
        near: f32,
        far: f32,
        seed: u32,
        step: u32,
        level: u32,
        jitter: u32,
        contraction: u32,
        ray_offset: u32,
    }
}

crate::push_constants! {
    struct WeightsPush {
        n_rays: u32,
        n: u32,
        near: f32,
        far: f32,
        raw_stride: u32,
        density_scale: f32,
        contraction: u32,
    }
}

crate::push_constants! {
    struct PdfPush {
        n_rays: u32,
        n: u32,
        m: u32,
        near: f32,
        far: f32,
        anneal: f32,
        seed: u32,
        step: u32,
        level: u32,
        jitter: u32,
        contraction: u32,
        ray_offset: u32,
    }
}

crate::push_constants! {
    struct ColourInputPush {
        n_samples: u32,
        n: u32,
        geo_dim: u32,
        app_dim: u32,
        in_pad: u32,
        density_stride: u32,
        app_mode: u32,
        mean_row: u32,
        sh_count: u32,
    }
}

crate::push_constants! {
    struct CompositePush {
        n_rays: u32,
        n: u32,
        bands: u32,
        near: f32,
        far: f32,
        density_stride: u32,
        density_scale: f32,
        background: u32,
        bg_value: f32,
        rgb_norm: f32,
        dist_norm: f32,
        train: u32,
        contraction: u32,
        grad_scaling: u32,
        seed: u32,
        step: u32,
        ray_offset: u32,
        depth_mode: u32,
        depth_norm: f32,
    }
}

crate::push_constants! {
    struct InterlevelPush {
        n_rays: u32,
        n_nerf: u32,
        n_prop: u32,
        near: f32,
        far: f32,
        raw_stride: u32,
        density_scale: f32,
        norm: f32,
        contraction: u32,
    }
}

crate::push_constants! {
    struct AppearanceGradPush {
        grads: u64,
        shift: u32,
        emb_offset: u32,
        n_rays: u32,
        n: u32,
        dim: u32,
        dx_stride: u32,
        dx_col: u32,
        pad: u32,
    }
}

crate::push_constants! {
    struct CopyColsPush {
        n: u32,
        cols: u32,
        src_stride: u32,
        src_col: u32,
        dst_stride: u32,
        dst_col: u32,
    }
}

/// Random-stream and jitter settings of one sampling level.
#[derive(Copy, Clone, Debug)]
pub struct Jitter {
    pub seed: u32,
    pub step: u32,
    pub level: u32,
    pub enabled: bool,
}

/// The background a ray sees where it is not opaque.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum BackgroundMode {
    /// The colour of the last (farthest) sample, learnable (nerfacto's default).
    LastSample,
    /// The same value in every band (black 0, white 1).
    Constant(f32),
    /// A uniform colour per ray and band from (seed, step, ray) (training only).
    Random { seed: u32, step: u32 },
}

/// Composite settings.
#[derive(Copy, Clone, Debug)]
pub struct CompositeParams {
    pub bands: usize,
    pub density_stride: usize,
    pub density_scale: f32,
    pub background: BackgroundMode,
    pub rgb_norm: f32,
    pub dist_norm: f32,
    pub train: bool,
    /// nerfacto's optional gradient scaling (field-output gradients times clamp(t_mid^2, 0, 1)).
    pub grad_scaling: bool,
    /// Depth supervision (with `CompositeBuffers::depth_targets`): the loss and its weight per ray
    /// (`depth_loss_mult` over the batch's ray weight). `None`: off, nothing read.
    pub depth: Option<(DepthLoss, f32)>,
}

/// Buffers of the composite kernel.
pub struct CompositeBuffers<'a> {
    pub edges: &'a GpuBuffer<f32>,
    pub density: &'a GpuBuffer<f32>,
    pub colours: &'a GpuBuffer<f32>,
    pub targets: &'a GpuBuffer<f32>,
    pub band_weights: &'a GpuBuffer<f32>,
    pub dy_density: &'a GpuBuffer<f32>,
    pub dy_colour: &'a GpuBuffer<f32>,
    pub weights: &'a GpuBuffer<f32>,
    pub ray_out: &'a GpuBuffer<f32>,
    /// Per ray (target distance, standard deviation) in the normalised frame; needed when `CompositeParams::depth`
    /// is set.
    pub depth_targets: Option<&'a GpuBuffer<f32>>,
}

/// Buffers of the interlevel kernel for one proposal level.
pub struct InterlevelBuffers<'a> {
    pub nerf_edges: &'a GpuBuffer<f32>,
    pub nerf_weights: &'a GpuBuffer<f32>,
    pub prop_edges: &'a GpuBuffer<f32>,
    pub prop_raw: &'a GpuBuffer<f32>,
    pub prop_weights: &'a GpuBuffer<f32>,
    pub prop_dy: &'a GpuBuffer<f32>,
    pub losses: &'a GpuBuffer<f32>,
}

/// Invocations per ray of the `_lanes` kernels (their workgroup; `glsl/render/ray_lanes.glsl`).
pub const RAY_LANES: usize = 32;

/// Most bins `pdf_resample_lanes` takes (its shared-memory cdf); more run the serial kernel.
pub const PDF_LANES_MAX_BINS: usize = 1024;

/// Most NeRF and proposal samples per ray `interlevel_lanes` takes (its shared-memory arrays); more run the serial
/// kernel.
pub const INTERLEVEL_LANES_MAX: (usize, usize) = (256, 1024);

/// Most NeRF samples per ray `composite_lanes` takes (its shared-memory arrays); more run the serial kernel.
pub const COMPOSITE_LANES_MAX_SAMPLES: usize = 256;

/// Most bands `composite` and `composite_lanes` take (their per-band arrays, `MAX_BANDS` in
/// `glsl/render/composite_io.glsl`).
pub const COMPOSITE_MAX_BANDS: usize = 128;

/// Refuses a band count the compositing kernels cannot hold, naming it.
pub fn check_bands(bands: usize) -> GpuResult<()> {
    if bands == 0 || bands > COMPOSITE_MAX_BANDS {
        return Err(GpuError::Config {
            what: "bands".into(),
            msg: format!(
                "{bands} bands: the renderer takes 1 to {COMPOSITE_MAX_BANDS} (the compositing kernels' arrays)"
            ),
        });
    }
    Ok(())
}

/// Whether the per-ray kernels run their GPU variants: the initial sampler one invocation per edge
/// (`sample_initial_edges`), and the proposal weights, resampling, interlevel loss, compositing and pose ray
/// gradient over [`RAY_LANES`] invocations per ray (`*_lanes`, with subgroup scans), instead of one invocation
/// walking each ray: `MSNERF_RAY_LANES` (`1` or `0`) when set, else on GPUs with subgroup arithmetic. Without them
/// a GPU runs a 4096-ray pass of these kernels as 4096 threads, each a serial loop over up to 512 samples
/// (docs/benchmarks.md); a CPU device (lavapipe) runs the serial loops in SIMD and was 3-10x slower with the
/// variants (same page). A value other than 0 or 1 is an error naming the variable.
pub fn default_ray_lanes(ctx: &Context) -> GpuResult<bool> {
    let caps = ctx.caps();
    match crate::util::env::settings().ray_lanes.as_deref() {
        None => Ok(!caps.is_cpu && caps.subgroup_arithmetic),
        Some("0") => Ok(false),
        Some("1") if caps.subgroup_arithmetic => Ok(true),
        Some("1") => Err(GpuError::Config {
            what: "MSNERF_RAY_LANES".into(),
            msg: "the device has no subgroup arithmetic, which the lanes kernels need".into(),
        }),
        Some(v) => Err(GpuError::Config { what: "MSNERF_RAY_LANES".into(), msg: format!("{v:?} is not 0 or 1") }),
    }
}

/// Refuses the lanes kernels on a device without subgroup arithmetic.
pub fn check_ray_lanes(ctx: &Context, lanes: bool) -> GpuResult<()> {
    if lanes && !ctx.caps().subgroup_arithmetic {
        return Err(GpuError::Config {
            what: "per-ray kernels".into(),
            msg: "the lanes kernels need subgroup arithmetic, which the device lacks".into(),
        });
    }
    Ok(())
}

/// The per-ray kernels over [`RAY_LANES`] invocations per ray.
struct LanesKernels {
    /// `sample_initial_edges`: one invocation per edge.
    sample_initial: Kernel<SampleInitialPush>,
    weights: Kernel<WeightsPush>,
    pdf: Kernel<PdfPush>,
    interlevel: Kernel<InterlevelPush>,
    composite: Kernel<CompositePush>,
}

/// Every render kernel, created once per context.
pub struct RenderKernels {
    ray_gen: Kernel<RayGenPush>,
    sample_initial: Kernel<SampleInitialPush>,
    weights: Kernel<WeightsPush>,
    pdf: Kernel<PdfPush>,
    /// The lanes variants, when chosen ([`default_ray_lanes`]).
    lanes: Option<LanesKernels>,
    colour_input: Kernel<ColourInputPush>,
    composite: Kernel<CompositePush>,
    interlevel: Kernel<InterlevelPush>,
    copy_cols: Kernel<CopyColsPush>,
    appearance_grad: Kernel<AppearanceGradPush>,
}

fn b(x: bool) -> u32 {
    u32::from(x)
}

impl RenderKernels {
    /// The kernels, with the per-ray variants [`default_ray_lanes`] picks for this device.
    pub fn new(ctx: &Context) -> GpuResult<Self> {
        Self::with_ray_lanes(ctx, default_ray_lanes(ctx)?)
    }

    /// As [`RenderKernels::new`], with the GPU variants of the per-ray kernels ([`default_ray_lanes`]) on or off.
    pub fn with_ray_lanes(ctx: &Context, lanes: bool) -> GpuResult<Self> {
        check_ray_lanes(ctx, lanes)?;
        let lanes = match lanes {
            true => Some(LanesKernels {
                sample_initial: Kernel::new(ctx, &shaders::SAMPLE_INITIAL_EDGES)?,
                weights: Kernel::new(ctx, &shaders::DENSITY_WEIGHTS_LANES)?,
                pdf: Kernel::new(ctx, &shaders::PDF_RESAMPLE_LANES)?,
                interlevel: Kernel::new(ctx, &shaders::INTERLEVEL_LANES)?,
                composite: Kernel::new(ctx, &shaders::COMPOSITE_LANES)?,
            }),
            false => None,
        };
        Ok(Self {
            ray_gen: Kernel::new(ctx, &shaders::RAY_GEN)?,
            sample_initial: Kernel::new(ctx, &shaders::SAMPLE_INITIAL)?,
            weights: Kernel::new(ctx, &shaders::DENSITY_WEIGHTS)?,
            pdf: Kernel::new(ctx, &shaders::PDF_RESAMPLE)?,
            lanes,
            colour_input: Kernel::new(ctx, &shaders::COLOUR_INPUT)?,
            composite: Kernel::new(ctx, &shaders::COMPOSITE)?,
            interlevel: Kernel::new(ctx, &shaders::INTERLEVEL)?,
            copy_cols: Kernel::new(ctx, &shaders::COPY_COLS)?,
            appearance_grad: Kernel::new(ctx, &shaders::APPEARANCE_GRAD)?,
        })
    }

    /// Rays through the pixels `pixels` (uint[3R]: camera, row, col).
    pub fn ray_gen(
        &self,
        rec: &mut Recorder,
        cameras: &GpuBuffer<crate::nerf::rays::GpuCamera>,
        pixels: &GpuBuffer<u32>,
        rays: RayBuffers,
        norms: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let bindings =
            [cameras.binding(), pixels.binding(), rays.origins.binding(), rays.dirs.binding(), norms.binding()];
        let push = RayGenPush { n_rays: rays.n_rays as u32 };
        rec.dispatch(&self.ray_gen, &bindings, &push, rays.n_rays as u64)
    }

    /// Initial piecewise sampler: edges (R x (n+1)) and hash inputs (R*n x 3).
    pub fn sample_initial(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        n: usize,
        jitter: Jitter,
        (edges, positions): (&GpuBuffer<f32>, &GpuBuffer<f32>),
    ) -> GpuResult<()> {
        let push = SampleInitialPush {
            n_rays: rays.n_rays as u32,
            n: n as u32,
            near: geo.near,
            far: geo.far,
            seed: jitter.seed,
            step: jitter.step,
            level: jitter.level,
            jitter: b(jitter.enabled),
            contraction: b(geo.contraction),
            ray_offset: rays.ray_offset,
        };
        let bindings = [rays.origins.binding(), rays.dirs.binding(), edges.binding(), positions.binding()];
        match &self.lanes {
            Some(l) => rec.dispatch(&l.sample_initial, &bindings, &push, (rays.n_rays * (n + 1)) as u64),
            None => rec.dispatch(&self.sample_initial, &bindings, &push, rays.n_rays as u64),
        }
    }

    /// Whether the lanes variants run ([`RenderKernels::with_ray_lanes`]).
    pub fn ray_lanes(&self) -> bool {
        self.lanes.is_some()
    }

    /// Weights of a level from its raw densities (column 0 of rows of `raw_stride`).
    #[allow(clippy::too_many_arguments)]
    pub fn weights(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        n: usize,
        edges: &GpuBuffer<f32>,
        raw: (&GpuBuffer<f32>, usize),
        density_scale: f32,
        weights: &GpuBuffer<f32>,
    ) -> GpuResult<()> {
        let push = WeightsPush {
            n_rays: rays.n_rays as u32,
            n: n as u32,
            near: geo.near,
            far: geo.far,
            raw_stride: raw.1 as u32,
            density_scale,
            contraction: b(geo.contraction),
        };
        let bindings =
            [edges.binding(), raw.0.binding(), weights.binding(), rays.origins.binding(), rays.dirs.binding()];
        match &self.lanes {
            Some(l) => rec.dispatch(&l.weights, &bindings, &push, (rays.n_rays * RAY_LANES) as u64),
            None => rec.dispatch(&self.weights, &bindings, &push, rays.n_rays as u64),
        }
    }

    /// PDF resampling from n bins to m samples (m + 1 edges), and their hash inputs.
    #[allow(clippy::too_many_arguments)]
    pub fn pdf_resample(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        (n, m): (usize, usize),
        anneal: f32,
        jitter: Jitter,
        (edges_in, weights): (&GpuBuffer<f32>, &GpuBuffer<f32>),
        (edges_out, positions): (&GpuBuffer<f32>, &GpuBuffer<f32>),
    ) -> GpuResult<()> {
        let push = PdfPush {
            n_rays: rays.n_rays as u32,
            n: n as u32,
            m: m as u32,
            near: geo.near,
            far: geo.far,
            anneal,
            seed: jitter.seed,
            step: jitter.step,
            level: jitter.level,
            jitter: b(jitter.enabled),
            contraction: b(geo.contraction),
            ray_offset: rays.ray_offset,
        };
        let bindings = [
            edges_in.binding(),
            weights.binding(),
            edges_out.binding(),
            positions.binding(),
            rays.origins.binding(),
            rays.dirs.binding(),
        ];
        match &self.lanes {
            Some(l) if n <= PDF_LANES_MAX_BINS => {
                rec.dispatch(&l.pdf, &bindings, &push, (rays.n_rays * RAY_LANES) as u64)
            }
            _ => rec.dispatch(&self.pdf, &bindings, &push, rays.n_rays as u64),
        }
    }

    /// Colour MLP input rows; `appearance` = (embeddings, camera index per ray, dim, Some(row) for a fixed row);
    /// `sh_count` of the 16 SH columns carry the direction's values, the rest are zero.
    #[allow(clippy::too_many_arguments)]
    pub fn colour_input(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        n: usize,
        density: (&GpuBuffer<f32>, usize),
        geo_dim: usize,
        sh_count: usize,
        appearance: Option<(Binding, &GpuBuffer<u32>, usize, Option<u32>)>,
        rows: (&GpuBuffer<f32>, usize),
    ) -> GpuResult<()> {
        let n_samples = rays.n_rays * n;
        let (emb, cams, app_dim, fixed) = match appearance {
            Some((e, c, d, f)) => (e, c.binding(), d, f),
            None => (density.0.binding(), density.0.binding(), 0, None),
        };
        let push = ColourInputPush {
            n_samples: n_samples as u32,
            n: n as u32,
            geo_dim: geo_dim as u32,
            app_dim: app_dim as u32,
            in_pad: rows.1 as u32,
            density_stride: density.1 as u32,
            app_mode: b(fixed.is_some()),
            mean_row: fixed.unwrap_or(0),
            sh_count: sh_count.min(crate::nn::sh::SH_DIM) as u32,
        };
        let bindings = [rays.dirs.binding(), density.0.binding(), cams, emb, rows.0.binding()];
        rec.dispatch(&self.colour_input, &bindings, &push, n_samples as u64)
    }

    /// NeRF-level compositing, losses and (in training) their backward.
    pub fn composite(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        n: usize,
        p: &CompositeParams,
        bufs: &CompositeBuffers,
    ) -> GpuResult<()> {
        let push = CompositePush {
            n_rays: rays.n_rays as u32,
            n: n as u32,
            bands: p.bands as u32,
            near: geo.near,
            far: geo.far,
            density_stride: p.density_stride as u32,
            density_scale: p.density_scale,
            background: match p.background {
                BackgroundMode::LastSample => 0,
                BackgroundMode::Constant(_) => 1,
                BackgroundMode::Random { .. } => 2,
            },
            bg_value: if let BackgroundMode::Constant(v) = p.background { v } else { 0.0 },
            rgb_norm: p.rgb_norm,
            dist_norm: p.dist_norm,
            train: b(p.train),
            contraction: b(geo.contraction),
            grad_scaling: b(p.grad_scaling),
            seed: if let BackgroundMode::Random { seed, .. } = p.background { seed } else { 0 },
            step: if let BackgroundMode::Random { step, .. } = p.background { step } else { 0 },
            ray_offset: rays.ray_offset,
            depth_mode: match p.depth {
                None => 0,
                Some((DepthLoss::DsNerf, _)) => 1,
                Some((DepthLoss::Urf, _)) => 2,
            },
            depth_norm: p.depth.map_or(0.0, |(_, w)| w),
        };
        check_bands(p.bands)?;
        if p.depth.is_some() && bufs.depth_targets.is_none() {
            return Err(GpuError::Dispatch {
                kernel: "composite".into(),
                msg: "depth supervision without a depth-target buffer".into(),
            });
        }
        // Off, the kernel never reads binding 11: any read-only buffer of the dispatch stands in.
        let depth_targets = bufs.depth_targets.unwrap_or(bufs.band_weights);
        let bindings = [
            bufs.edges.binding(),
            bufs.density.binding(),
            bufs.colours.binding(),
            bufs.targets.binding(),
            bufs.band_weights.binding(),
            bufs.dy_density.binding(),
            bufs.dy_colour.binding(),
            bufs.weights.binding(),
            bufs.ray_out.binding(),
            rays.origins.binding(),
            rays.dirs.binding(),
            depth_targets.binding(),
        ];
        match &self.lanes {
            Some(l) if n <= COMPOSITE_LANES_MAX_SAMPLES => {
                rec.dispatch(&l.composite, &bindings, &push, (rays.n_rays * RAY_LANES) as u64)
            }
            _ => rec.dispatch(&self.composite, &bindings, &push, rays.n_rays as u64),
        }
    }

    /// Interlevel loss of one proposal level and its backward into `prop_dy` (column 0 of rows of `raw_stride`).
    #[allow(clippy::too_many_arguments)]
    pub fn interlevel(
        &self,
        rec: &mut Recorder,
        rays: RayBuffers,
        geo: Geometry,
        (n_nerf, n_prop): (usize, usize),
        raw_stride: usize,
        density_scale: f32,
        norm: f32,
        bufs: &InterlevelBuffers,
    ) -> GpuResult<()> {
        let push = InterlevelPush {
            n_rays: rays.n_rays as u32,
            n_nerf: n_nerf as u32,
            n_prop: n_prop as u32,
            near: geo.near,
            far: geo.far,
            raw_stride: raw_stride as u32,
            density_scale,
            norm,
            contraction: b(geo.contraction),
        };
        let bindings = [
            bufs.nerf_edges.binding(),
            bufs.nerf_weights.binding(),
            bufs.prop_edges.binding(),
            bufs.prop_raw.binding(),
            bufs.prop_weights.binding(),
            bufs.prop_dy.binding(),
            bufs.losses.binding(),
            rays.origins.binding(),
            rays.dirs.binding(),
        ];
        match &self.lanes {
            Some(l) if n_nerf <= INTERLEVEL_LANES_MAX.0 && n_prop <= INTERLEVEL_LANES_MAX.1 => {
                rec.dispatch(&l.interlevel, &bindings, &push, (rays.n_rays * RAY_LANES) as u64)
            }
            _ => rec.dispatch(&self.interlevel, &bindings, &push, rays.n_rays as u64),
        }
    }

    /// Copies `cols` columns of `n` rows between row-major matrices: (buffer, stride, first column).
    pub fn copy_cols(
        &self,
        rec: &mut Recorder,
        n: usize,
        cols: usize,
        src: (&GpuBuffer<f32>, usize, usize),
        dst: (&GpuBuffer<f32>, usize, usize),
    ) -> GpuResult<()> {
        let push = CopyColsPush {
            n: n as u32,
            cols: cols as u32,
            src_stride: src.1 as u32,
            src_col: src.2 as u32,
            dst_stride: dst.1 as u32,
            dst_col: dst.2 as u32,
        };
        rec.dispatch(&self.copy_cols, &[src.0.binding(), dst.0.binding()], &push, (n * cols) as u64)
    }

    /// Scatters the appearance columns of the colour MLP's input gradient into the embedding gradients.
    #[allow(clippy::too_many_arguments)]
    pub fn appearance_grad(
        &self,
        rec: &mut Recorder,
        grads: &crate::gpu::LargeArray<f32>,
        emb_offset: usize,
        (n_rays, n): (usize, usize),
        dim: usize,
        dx: (&GpuBuffer<f32>, usize, usize),
        cam_idx: &GpuBuffer<u32>,
    ) -> GpuResult<()> {
        let push = AppearanceGradPush {
            grads: grads.table_address()?,
            shift: grads.chunk_shift(),
            emb_offset: emb_offset as u32,
            n_rays: n_rays as u32,
            n: n as u32,
            dim: dim as u32,
            dx_stride: dx.1 as u32,
            dx_col: dx.2 as u32,
            pad: 0,
        };
        // One invocation per (ray, dimension): the ray's samples are summed before the one atomic.
        let work = (n_rays * dim) as u64;
        rec.dispatch_named(
            "appearance_grad",
            &self.appearance_grad,
            &[dx.0.binding(), cam_idx.binding()],
            &grads.deps(),
            &push,
            work,
        )
    }
}
