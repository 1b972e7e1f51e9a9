//! `msnerf eval RUN [--split eval|train]`: renders every view of a split and reports PSNR (data range 1, stated in the
//! output) and SSIM (scikit-image's Gaussian convention) per band, per view and overall, with the render time; JSON in
//! nerfstudio's `ns-eval` layout plus per-band entries. LPIPS (AlexNet, on natural-colour composites) when
//! `--lpips-weights` names a weights file; otherwise it is reported as not computed. `--depth`: the rendered median
//! depth against the dataset's depth maps ([`crate::output::metrics::depth`]). `--registered-truth DIR`: band
//! agreement through the frame camera ([`crate::nerf::registered_eval`]).

use super::Cli;
use crate::data::Split;
use crate::gpu::Context;
use crate::nerf::evaluate::evaluate;
use crate::nerf::run::LoadedRun;
use crate::output::metrics::lpips::Lpips;
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
    /// AlexNet-LPIPS weights (safetensors; `tools/export_lpips_weights.py` writes them): computes LPIPS on the
    /// natural-colour composites (bands nearest 660, 555, 450 nm)
    #[arg(long)]
    pub lpips_weights: Option<PathBuf>,
    /// Also compare the rendered median depth with the dataset's depth maps (`depth_file_path`): median |error|,
    /// signed bias (+ = in front of the surface) and the fraction within 0.5 and 1 pixel footprint, per view and
    /// overall. An error when the frames have no depth maps.
    #[arg(long)]
    pub depth: bool,
    /// Also compare every band, rendered through the frame camera, with the true registered images in this folder
    /// (`<frame stem>.tif`; `msnerf simulate` writes them as truth/registered/ for `rig_parallax` scenes), apart at
    /// depth discontinuities and elsewhere; written to RUN/eval_registered.json (or beside --output)
    #[arg(long)]
    pub registered_truth: Option<PathBuf>,
}

pub fn parse_split(s: &str) -> anyhow::Result<Split> {
    match s {
        "eval" => Ok(Split::Eval),
        "train" => Ok(Split::Train),
        _ => anyhow::bail!("--split: expected `eval` or `train`, got `{s}`"),
    }
}

pub fn run(cli: &Cli, a: &EvalArgs) -> anyhow::Result<()> {
    let split = parse_split(&a.split)?;
    if let Some(out) = &a.output {
        let run_files = ["config.yaml", "dataset.json", "checkpoints/latest.msnp", "checkpoints/latest.json"]
            .map(|f| a.run.join(f));
        let inputs: Vec<(&str, &std::path::Path)> = run_files.iter().map(|p| ("run's", p.as_path())).collect();
        crate::util::atomic::check_not_an_input(out, &inputs)?;
    }
    let ctx = Context::new(&cli.context_desc())?;
    let lpips = a.lpips_weights.as_deref().map(Lpips::load).transpose().map_err(anyhow::Error::msg)?;
    let mut run = LoadedRun::load(&ctx, &a.run)?;
    let report = evaluate(&mut run, split, None, lpips.as_ref(), a.depth)?;
    let out = a.output.clone().unwrap_or_else(|| a.run.join("eval.json"));
    report.write(&out)?;
    if let Some(dir) = &a.registered_truth {
        let reg = crate::nerf::registered_eval::evaluate_registered(&mut run, split, dir, None)?;
        let path = out.with_file_name("eval_registered.json");
        crate::util::atomic::write_bytes(&path, serde_json::to_string_pretty(&reg)?.as_bytes())?;
        let (e, r) = (&reg.discontinuity, &reg.elsewhere);
        println!(
            "registered truth: mean band RMSE {:.4} at depth discontinuities ({} px), {:.4} elsewhere ({} px); \
             ({}-{})/({}+{}) RMSE {:.4} / {:.4}; report: {}",
            e.mean_rmse,
            e.pixels,
            r.mean_rmse,
            r.pixels,
            reg.index_bands[0],
            reg.index_bands[1],
            reg.index_bands[0],
            reg.index_bands[1],
            e.index_rmse,
            r.index_rmse,
            path.display()
        );
    }
    if a.json {
        println!("{}", report.to_json());
    } else {
        print!("{}", report.table());
        println!("report: {}", out.display());
    }
    Ok(())
}
