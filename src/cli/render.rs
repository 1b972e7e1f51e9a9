//! `msnerf render RUN --views eval|train|all|orbit|PATH.json --out DIR`: per view a multi-band float32 GeoTIFF with
//! band names (GDAL metadata), optional EXR, PNG previews (natural colour, CIR, NDVI with a colour bar, depth,
//! accumulation, error against ground truth), vegetation indices chosen by name as float GeoTIFFs, and a contact
//! sheet. Dataset frames are named after their images; novel views (`orbit`: [`crate::nerf::views`], a camera path:
//! [`crate::nerf::camera_path`]) are `orbit_000`, `path_000`, ... and have no error preview (no ground truth).

use super::Cli;
use crate::data::pose::PoseTransform;
use crate::data::Split;
use crate::gpu::Context;
use crate::nerf::camera_path::load_camera_path;
use crate::nerf::evaluate::ground_truth_of;
use crate::nerf::run::{LoadedRun, RenderedView};
use crate::nerf::views::{orbit_views, NovelView, OrbitDesc};
use crate::output::image::SpectralImage;
use crate::output::metrics::{image_metrics, MetricOptions};
use crate::output::raster::indices::VegetationIndex;
use crate::output::raster::preview::Rgb8;
use crate::products::views::{
    check_index_bands, parse_stretch, write_contact_sheet, write_novel_view, write_outputs, write_view, ViewOptions,
};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Run folder written by `msnerf train`, or a `msnerf partition` folder whose blocks were trained (every block
    /// renders each view, blended over the overlaps)
    pub run: PathBuf,
    /// Views to render: eval, train, all (dataset frames), orbit (novel views circling the scene), or a camera-path
    /// JSON file (nerfstudio's viewer camera_path.json, or a list of transforms.json-style frames)
    #[arg(long, default_value = "eval")]
    pub views: String,
    /// Output folder
    #[arg(long)]
    pub out: PathBuf,
    /// Also write an OpenEXR per view
    #[arg(long)]
    pub exr: bool,
    /// Vegetation indices to write as float GeoTIFFs (comma separated, e.g. NDVI,NDRE720,GNDVI)
    #[arg(long, value_delimiter = ',', default_value = "NDVI")]
    pub indices: Vec<String>,
    /// Preview stretch: `reflectance` (fixed 0-0.5 visible, 0-0.8 NIR) or `percentile` (2-98 %)
    #[arg(long, default_value = "reflectance")]
    pub stretch: String,
    /// At most this many views in the contact sheet (0: no contact sheet)
    #[arg(long, default_value_t = 8)]
    pub sheet_views: usize,
    #[command(flatten)]
    pub orbit: OrbitArgs,
    /// RUN is a `msnerf partition` folder: render with the blocks that finished (without it, a block that did not
    /// finish is an error)
    #[arg(long)]
    pub partial: bool,
    /// RUN is a `msnerf partition` folder: host memory for the blend's accumulators, MiB (views are rendered in
    /// groups that fit)
    #[arg(long, default_value_t = 1024)]
    pub blend_mib: usize,
}

/// The orbit's flags (`--views orbit` only); defaults come from the training cameras.
#[derive(clap::Args, Debug, Default, Clone)]
pub struct OrbitArgs {
    /// Number of orbit views [default: 24]
    #[arg(long)]
    pub orbit_views: Option<usize>,
    /// Orbit radius in world units [default: the training cameras' mean horizontal distance from their look-at centre]
    #[arg(long, value_parser = super::finite_f64)]
    pub orbit_radius: Option<f64>,
    /// Orbit height above the look-at centre in world units [default: the training cameras' mean height]
    #[arg(long, value_parser = super::finite_f64, allow_hyphen_values = true)]
    pub orbit_height: Option<f64>,
    /// Camera pitch in degrees, negative looking down [default: looking at the centre]
    #[arg(long, value_parser = super::finite_f64, allow_hyphen_values = true)]
    pub orbit_pitch_deg: Option<f64>,
}

impl OrbitArgs {
    fn any(&self) -> bool {
        self.orbit_views.is_some()
            || self.orbit_radius.is_some()
            || self.orbit_height.is_some()
            || self.orbit_pitch_deg.is_some()
    }

    fn desc(&self) -> OrbitDesc {
        OrbitDesc {
            views: self.orbit_views.unwrap_or(24),
            radius: self.orbit_radius,
            height: self.orbit_height,
            pitch_deg: self.orbit_pitch_deg,
        }
    }
}

/// What `--views` asks for.
enum Views {
    Frames(Vec<usize>),
    Novel(Vec<NovelView>),
}

const VIEWS_CHOICES: &str = "eval, train, all, orbit or a camera-path .json file";

/// The views `--views` asks for of `ds`; novel views in the normalised frame of `transform`.
fn parse_views(ds: &crate::data::Dataset, transform: &PoseTransform, a: &RenderArgs) -> anyhow::Result<Views> {
    let views = match a.views.as_str() {
        "all" => Views::Frames((0..ds.frames.len()).collect()),
        "eval" => Views::Frames(ds.split_indices(Split::Eval)),
        "train" => Views::Frames(ds.split_indices(Split::Train)),
        "orbit" => Views::Novel(orbit_views(ds, transform, &a.orbit.desc())?),
        s if s.ends_with(".json") || Path::new(s).is_file() => {
            Views::Novel(load_camera_path(Path::new(s), ds, transform)?)
        }
        s => anyhow::bail!("--views {s}: expected {VIEWS_CHOICES}"),
    };
    match &views {
        Views::Frames(f) if f.is_empty() => anyhow::bail!("--views {}: no frames", a.views),
        _ => Ok(views),
    }
}

impl RenderArgs {
    /// The per-view products the flags ask for (index names and the stretch checked).
    pub fn view_options(&self) -> anyhow::Result<ViewOptions> {
        let indices = self.indices.iter().map(|n| VegetationIndex::parse(n)).collect::<Result<_, _>>()?;
        Ok(ViewOptions { exr: self.exr, indices, stretch: parse_stretch(&self.stretch)? })
    }
}

pub fn run(cli: &Cli, a: &RenderArgs) -> anyhow::Result<()> {
    // Check every flag before rendering anything, so a typo does not leave a half-filled output folder.
    let vo = a.view_options()?;
    let is_path = a.views.ends_with(".json") || Path::new(&a.views).is_file();
    if !is_path && !["eval", "train", "all", "orbit"].contains(&a.views.as_str()) {
        anyhow::bail!("--views {}: expected {VIEWS_CHOICES}", a.views);
    }
    if a.orbit.any() && a.views != "orbit" {
        anyhow::bail!("--orbit-views, --orbit-radius, --orbit-height and --orbit-pitch-deg need --views orbit");
    }
    let ctx = Context::new(&cli.context_desc())?;
    if crate::scale::is_blocks_folder(&a.run) {
        return run_blocks(&ctx, a);
    }
    anyhow::ensure!(!a.partial, "--partial: {} is a run folder, not a `msnerf partition` folder", a.run.display());
    let mut run = LoadedRun::load(&ctx, &a.run)?;
    check_index_bands(&run.ds.bands, &vo)?;
    // Every view is known (and a camera path fully checked) before the output folder is touched.
    let views = parse_views(&run.ds, &run.transform, a)?;
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let mut sheet: Vec<(String, Rgb8)> = Vec::new();
    let n = match &views {
        Views::Frames(f) => f.len(),
        Views::Novel(v) => v.len(),
    };
    if let Views::Novel(v) = &views {
        run.set_novel_views(v)?;
    }
    for k in 0..n {
        let (v, name) = match &views {
            Views::Frames(f) => (write_view(&mut run, f[k], &a.out, &vo)?, run.ds.frames[f[k]].name.clone()),
            Views::Novel(nv) => (write_novel_view(&mut run, k, &a.out, &vo)?, nv[k].name.clone()),
        };
        if k < a.sheet_views {
            sheet.extend(v.tiles);
        }
        println!("rendered {name} ({}/{n})", k + 1);
    }
    write_sheet(&sheet, n, a)
}

fn write_sheet(sheet: &[(String, Rgb8)], n: usize, a: &RenderArgs) -> anyhow::Result<()> {
    if a.sheet_views == 0 {
        println!("outputs in {} (no contact sheet: --sheet-views 0)", a.out.display());
        return Ok(());
    }
    write_contact_sheet(sheet, sheet.len() / n.min(a.sheet_views).max(1), &a.out)?;
    println!("outputs in {}", a.out.display());
    Ok(())
}

/// `render BLOCKS`: the views of the partitioned dataset, posed in its world frame, rendered by every block and
/// blended ([`crate::scale::merge_render`]); dataset frames get an error preview and a PSNR against their image
/// (`metrics.json`: the whole scene's views, not one block's).
fn run_blocks(ctx: &Context, a: &RenderArgs) -> anyhow::Result<()> {
    use crate::scale::merge_render::{render_blocks, WorldView};
    let vo = a.view_options()?;
    let blocks = crate::scale::runner::read_blocks(&a.run)?;
    let ds = crate::data::load_dataset(&blocks.source, &crate::data::LoadOptions::default())?;
    let transform = ds.pose_transform();
    // (view in the world frame, its dataset frame)
    let views: Vec<(WorldView, Option<usize>)> = match parse_views(&ds, &transform, a)? {
        Views::Frames(frames) => frames
            .into_iter()
            .map(|f| {
                let fr = &ds.frames[f];
                (WorldView { name: fr.name.clone(), camera: fr.camera, c2w: fr.c2w }, Some(f))
            })
            .collect(),
        Views::Novel(novel) => novel
            .into_iter()
            .map(|v| (WorldView { name: v.name, camera: v.camera, c2w: transform.pose_to_world(&v.c2w) }, None))
            .collect(),
    };
    anyhow::ensure!(a.blend_mib > 0, "--blend-mib must be > 0");
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let world: Vec<WorldView> = views.iter().map(|(v, _)| v.clone()).collect();
    let mut sheet: Vec<(String, Rgb8)> = Vec::new();
    let mut metrics = Vec::new();
    let mut write = |k: usize, rv: RenderedView| -> anyhow::Result<()> {
        let (v, frame) = &views[k];
        let stem = Path::new(&v.name).file_stem().map_or(v.name.clone(), |s| s.to_string_lossy().into_owned());
        // With `rig_cameras` the image is not the frame camera's registered view (see `write_view`).
        let gt = match frame {
            Some(f) if ds.rig.is_none() => Some(ground_truth_of(&ds, *f)?),
            _ => None,
        };
        let files = write_outputs(&ds.bands, &rv, &stem, gt.as_ref().map(|g| &g.0), &a.out, &vo)?;
        if let Some((gt, mask)) = &gt {
            let img = SpectralImage::from_interleaved(rv.width, rv.height, ds.bands.clone(), &rv.colour)?;
            let m = image_metrics(&img, gt, mask.as_deref(), &MetricOptions::default())?;
            println!("{}: PSNR {:.2} dB, SSIM {:.4} (blended)", v.name, m.psnr, m.ssim);
            metrics.push(serde_json::json!({"view": v.name, "psnr": m.psnr, "ssim": m.ssim}));
        }
        if k < a.sheet_views {
            sheet.extend(files.tiles);
        }
        Ok(())
    };
    let progress = |b: &str, j: usize, n: usize| println!("{b}: rendered {j}/{n}");
    let stats = render_blocks(ctx, &a.run, &blocks, &world, a.partial, a.blend_mib << 20, progress, |k, rv| {
        write(k, rv).map_err(|e| crate::scale::ScaleError::Output { path: a.out.clone(), reason: format!("{e:#}") })
    })?;
    println!(
        "blocks {}; {} of {} pixels blended from more than one block",
        stats.blocks.join(", "),
        stats.blended_pixels,
        stats.pixels
    );
    for m in &stats.missing {
        println!("left out (not trained or not finished): {m}");
    }
    if !metrics.is_empty() {
        let mean = metrics.iter().filter_map(|m| m["psnr"].as_f64()).sum::<f64>() / metrics.len() as f64;
        println!("mean PSNR over {} views: {mean:.2} dB", metrics.len());
        let json =
            serde_json::json!({"views": metrics, "mean_psnr": mean, "blocks": stats.blocks, "missing": stats.missing});
        crate::util::atomic::write_bytes(&a.out.join("metrics.json"), serde_json::to_string_pretty(&json)?.as_bytes())?;
    }
    write_sheet(&sheet, views.len(), a)
}
