//! `msnerf export pointcloud RUN --out cloud.ply|cloud.las`: a multispectral point cloud in the dataset's own world
//! frame and units (see `msnerf::nerf::export`), with statistical outlier removal, an optional crop box and a target
//! point count. PLY carries every band as float and a display RGB; LAS 1.4 point format 8 carries RGB + NIR and the
//! other bands as Extra Bytes. `--normals` adds each point's surface normal from the density field (PLY `nx ny nz`,
//! LAS Extra Bytes `NormalX/Y/Z`).

use super::Cli;
use crate::gpu::Context;
use crate::nerf::export::{export_points, ExportOptions};
use crate::nerf::run::LoadedRun;
use crate::output::pointcloud::{self, PointCloud};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    #[command(subcommand)]
    pub what: ExportWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum ExportWhat {
    /// Multispectral point cloud (.ply or .las)
    Pointcloud(PointcloudArgs),
}

#[derive(clap::Args, Debug)]
pub struct PointcloudArgs {
    /// Run folder written by `msnerf train`
    pub run: PathBuf,
    /// Output file: .ply or .las
    #[arg(long)]
    pub out: PathBuf,
    /// Training rays to render before filtering
    #[arg(long, default_value_t = 200_000)]
    pub rays: usize,
    /// Keep rays whose accumulation (opacity) is at least this
    #[arg(long, default_value_t = 0.5)]
    pub min_accumulation: f32,
    /// Statistical outlier removal: neighbours and standard-deviation ratio (0 neighbours turns it off)
    #[arg(long, default_value_t = 20)]
    pub outlier_neighbours: usize,
    #[arg(long, default_value_t = 10.0)]
    pub outlier_std_ratio: f64,
    /// Axis-aligned crop box in world units: minx,miny,minz,maxx,maxy,maxz
    #[arg(long, value_delimiter = ',', num_args = 6)]
    pub crop: Option<Vec<f64>>,
    /// At most this many points (random, seeded subsample)
    #[arg(long)]
    pub points: Option<usize>,
    #[arg(long, default_value_t = 42)]
    pub seed: u64,
    /// Also write surface normals: -grad(density) of the NeRF field at each point, facing the camera that saw it
    #[arg(long)]
    pub normals: bool,
}

/// Filters a cloud as the flags ask.
pub fn filter(mut cloud: PointCloud, a: &PointcloudArgs) -> anyhow::Result<PointCloud> {
    if let Some(b) = &a.crop {
        let inside = |p: &[f64; 3]| (0..3).all(|k| p[k] >= b[k] && p[k] <= b[k + 3]);
        cloud = pointcloud::filter::crop(&cloud, inside)?.0;
    }
    if a.outlier_neighbours > 0 && cloud.len() > a.outlier_neighbours {
        cloud = pointcloud::filter::remove_statistical_outliers(&cloud, a.outlier_neighbours, a.outlier_std_ratio)?.0;
    }
    if let Some(n) = a.points {
        cloud = pointcloud::filter::subsample(&cloud, n, a.seed)?.0;
    }
    Ok(cloud)
}

pub fn write_cloud(cloud: &PointCloud, out: &std::path::Path) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("ply") => pointcloud::write_ply(out, cloud, &Default::default())?,
        Some("las") => pointcloud::write_las(out, cloud, &Default::default())?,
        _ => anyhow::bail!("--out {}: the file must end in .ply or .las", out.display()),
    }
    Ok(())
}

pub fn run(cli: &Cli, a: &ExportArgs) -> anyhow::Result<()> {
    let ExportWhat::Pointcloud(a) = &a.what;
    let ext_ok = matches!(a.out.extension().and_then(|e| e.to_str()), Some("ply" | "las" | "PLY" | "LAS"));
    anyhow::ensure!(ext_ok, "--out {}: the file must end in .ply or .las", a.out.display());
    let ctx = Context::new(&cli.context_desc())?;
    let mut run = LoadedRun::load(&ctx, &a.run).map_err(anyhow::Error::msg)?;
    let opts = ExportOptions { rays: a.rays, min_accumulation: a.min_accumulation, seed: a.seed, normals: a.normals };
    let raw = export_points(&mut run, &opts).map_err(anyhow::Error::msg)?;
    let n_raw = raw.len();
    let cloud = filter(raw, a)?;
    write_cloud(&cloud, &a.out)?;
    println!(
        "{} points ({} rays rendered, {} above accumulation {}) -> {}",
        cloud.len(),
        a.rays,
        n_raw,
        a.min_accumulation,
        a.out.display()
    );
    Ok(())
}
