//! `msnerf eval RUN [--split eval|train]`: renders every view of a split and reports PSNR (data range 1, stated in the
//! output) and SSIM (scikit-image's Gaussian convention) per band, per view and overall, with the render time; JSON in
//! nerfstudio's `ns-eval` layout plus per-band entries. LPIPS is reported as not computed.

use super::Cli;
use crate::data::Split;
use crate::gpu::Context;
use crate::nerf::run::LoadedRun;
use crate::output::image::SpectralImage;
use crate::output::metrics::{image_metrics, EvalReport, MetricOptions, ViewEval};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Run folder written by `msnerf train`
    pub run: PathBuf,
    /// Which views to evaluate
    #[arg(long, default_value = "eval")]
    pub split: String,
    /// Where to write the JSON report (default: RUN/eval.json)
    #[arg(long)]
    pub output: Option<PathBuf>,
    /// Print the JSON instead of the table
    #[arg(long)]
    pub json: bool,
}

pub fn parse_split(s: &str) -> anyhow::Result<Split> {
    match s {
        "eval" => Ok(Split::Eval),
        "train" => Ok(Split::Train),
        _ => anyhow::bail!("--split: expected `eval` or `train`, got `{s}`"),
    }
}

/// Ground truth of a frame as a spectral image and its mask.
pub fn ground_truth(run: &LoadedRun, frame: usize) -> anyhow::Result<(SpectralImage, Option<Vec<bool>>)> {
    let r = run.ds.read_frame(frame)?;
    let data: Vec<f32> = (0..r.bands).flat_map(|b| r.band_f32(b)).collect();
    let img = SpectralImage::from_planar(r.width as usize, r.height as usize, run.ds.bands.clone(), data)?;
    let mask = r.mask.as_ref().map(|m| m.iter().map(|&v| v != 0).collect());
    Ok((img, mask))
}

/// Evaluates the views of `split` (at most `max_views`, evenly spread, when given).
pub fn evaluate(run: &mut LoadedRun, split: Split, max_views: Option<usize>) -> anyhow::Result<EvalReport> {
    let mut frames = run.ds.split_indices(split);
    if let Some(m) = max_views.filter(|&m| m > 0 && m < frames.len()) {
        frames = (0..m).map(|k| frames[k * frames.len() / m]).collect();
    }
    anyhow::ensure!(!frames.is_empty(), "{}: the {split:?} split has no frames", run.ds.transforms_path.display());
    let mut views = Vec::new();
    for f in frames {
        let rv = run.render_view(f).map_err(anyhow::Error::msg)?;
        let pred = SpectralImage::from_interleaved(rv.width, rv.height, run.ds.bands.clone(), &rv.colour)?;
        let (gt, mask) = ground_truth(run, f)?;
        let metrics = image_metrics(&pred, &gt, mask.as_deref(), &MetricOptions { data_range: 1.0 })?;
        views.push(ViewEval {
            name: run.ds.frames[f].name.clone(),
            metrics,
            num_rays: rv.width * rv.height,
            render_seconds: Some(rv.seconds),
        });
    }
    let exp = run.ds.root.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    Ok(EvalReport::new(
        &exp,
        &format!("msnerf-{}", run.cfg.name),
        &run.checkpoint.display().to_string(),
        &run.ds.bands,
        &views,
        1.0,
    )?)
}

pub fn run(cli: &Cli, a: &EvalArgs) -> anyhow::Result<()> {
    let split = parse_split(&a.split)?;
    let ctx = Context::new(&cli.context_desc())?;
    let mut run = LoadedRun::load(&ctx, &a.run).map_err(anyhow::Error::msg)?;
    let report = evaluate(&mut run, split, None)?;
    let out = a.output.clone().unwrap_or_else(|| a.run.join("eval.json"));
    report.write(&out)?;
    if a.json {
        println!("{}", report.to_json());
    } else {
        print!("{}", report.table());
        println!("report: {}", out.display());
    }
    Ok(())
}
