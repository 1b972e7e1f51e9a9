//! `msnerf plan --model M --hardware H [--data DIR | --views N --width W --height H --bands B] [--fit] [--json]`:
//! the VRAM and host-memory plan of training M on the hardware profile H (see `msnerf::plan`). Exits non-zero
//! with the reasons when the plan does not fit.

use super::Cli;
use crate::data::{load_dataset, LoadOptions};
use crate::gpu::Context;
use crate::nerf::config::chunk_within_batch;
use crate::nerf::config::{ActivationStorage, ModelConfig};
use crate::plan::fit::profile_rays;
use crate::plan::{plan, DatasetShape, DeviceRule, HardwareProfile, PlanRequest, RayCounts};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct PlanArgs {
    /// Model: nerfacto, multispectral-nerf, tiny, or a YAML file
    #[arg(long, default_value = "multispectral-nerf")]
    pub model: String,
    /// Hardware profile: rtx2080ti-11gb, a100-80gb, lavapipe, a YAML file, or `auto` (this device)
    #[arg(long)]
    pub hardware: String,
    /// Dataset folder (its views, image size, bands and sample type)
    #[arg(long, conflicts_with_all = ["views", "width", "height", "bands"])]
    pub data: Option<PathBuf>,
    /// Number of views (all counted as training views), without a dataset
    #[arg(long, default_value_t = 4000)]
    pub views: usize,
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    #[arg(long, default_value_t = 960)]
    pub height: u32,
    #[arg(long, default_value_t = 6)]
    pub bands: usize,
    /// Bytes per stored sample without a dataset (2: 16-bit TIFF)
    #[arg(long, default_value_t = 2)]
    pub sample_bytes: u64,
    /// Override the profile's training rays per batch
    #[arg(long)]
    pub rays_per_batch: Option<usize>,
    /// Override the profile's training rays per GPU pass
    #[arg(long)]
    pub rays_per_chunk: Option<usize>,
    /// Override the profile's evaluation rays per pass
    #[arg(long)]
    pub eval_rays_per_chunk: Option<usize>,
    /// Override the model's storage of MLP hidden activations (f16: half their memory; sums stay fp32)
    #[arg(long, value_enum)]
    pub mlp_activations: Option<ActivationStorage>,
    /// Find the largest training and evaluation chunks that fit
    #[arg(long)]
    pub fit: bool,
    /// Print the plan as JSON
    #[arg(long)]
    pub json: bool,
    /// Use the profile's footprint rule and limits even when its device is present
    #[arg(long)]
    pub no_device: bool,
}

pub fn run(cli: &Cli, a: &PlanArgs) -> anyhow::Result<()> {
    let mut model = ModelConfig::resolve(&a.model)?;
    if let Some(v) = a.mlp_activations {
        model.mlp_activations = v;
    }
    let data = match &a.data {
        Some(d) => DatasetShape::from_dataset(&load_dataset(d, &LoadOptions::default())?),
        None => {
            if a.views == 0 || a.width == 0 || a.height == 0 || a.bands == 0 || a.sample_bytes == 0 {
                anyhow::bail!("--views, --width, --height, --bands and --sample-bytes must be > 0");
            }
            DatasetShape::synthetic(a.views, a.width, a.height, a.bands, a.sample_bytes)
        }
    };
    // A device is used when the profile is `auto` or names a device that is present.
    let ctx = if a.no_device { None } else { Context::new(&cli.context_desc()).ok() };
    let (profile, dev) = if a.hardware == "auto" {
        let ctx = ctx.ok_or_else(|| anyhow::anyhow!("--hardware auto needs a Vulkan device and found none"))?;
        (crate::plan::train::resolve_profile(&ctx, "auto", &model, &data)?, DeviceRule::from_context(&ctx))
    } else {
        let p = HardwareProfile::resolve(&a.hardware)?;
        let dev = match ctx.filter(|c| p.matches(c)) {
            Some(c) => DeviceRule::from_context(&c),
            None => DeviceRule::from_profile(&p.gpu),
        };
        (p, dev)
    };
    let base = profile_rays(&profile);
    let batch = a.rays_per_batch.unwrap_or(base.rays_per_batch);
    let rays = RayCounts {
        rays_per_batch: batch,
        rays_per_chunk: a.rays_per_chunk.unwrap_or(chunk_within_batch(base.rays_per_chunk, batch)),
        eval_rays_per_chunk: a.eval_rays_per_chunk.unwrap_or(base.eval_rays_per_chunk),
    };
    if rays.rays_per_batch == 0 || rays.rays_per_chunk == 0 || rays.eval_rays_per_chunk == 0 {
        anyhow::bail!("ray counts must be > 0");
    }
    let req = PlanRequest { model: &model, profile: &profile, data, rays: Some(rays), fit: a.fit };
    let p = plan(&req, &dev)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
    } else {
        print!("{}", crate::plan::report::text(&p));
    }
    if !p.fits {
        anyhow::bail!("the plan does not fit {}: {}", p.profile, p.problems().join("; "));
    }
    Ok(())
}
