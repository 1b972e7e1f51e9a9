//! `msnerf sweep --grid G.yaml --out DIR (--data DIR | --builtin-scene NAME) [--report PAGE.md]`: trains every
//! cell of a grid under the same budget (resuming: finished cells are skipped), then writes `cells.csv`,
//! `points.csv`, `kernels.csv`, `sweep.json`, `plots/` and `report.md` into DIR (see `msnerf::sweep`).

use super::Cli;
use crate::gpu::Context;
use crate::sweep::report::{report_markdown, ReportContext};
use crate::sweep::table::{write_tables, Machine};
use crate::sweep::{plots, run_sweep, Grid, SweepOptions};
use crate::util::atomic;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// Grid file (configs/sweeps/*.yaml)
    #[arg(long)]
    pub grid: PathBuf,
    /// Output folder: cells/<id>/ per configuration, CSV, JSON, plots and report.md; rerunning resumes
    #[arg(long)]
    pub out: PathBuf,
    /// Dataset folder (transforms.json with bands)
    #[arg(long, conflicts_with = "builtin_scene", required_unless_present = "builtin_scene")]
    pub data: Option<PathBuf>,
    /// Simulate a built-in scene (campus, ci-small, ci-textured, rig-low, flight-rural, flight-urban) or a scene YAML into OUT/data and sweep on it
    #[arg(long)]
    pub builtin_scene: Option<String>,
    /// Also write the report here, with its plots in a folder of the same name (e.g. docs/accuracy-vs-time.md
    /// and docs/accuracy-vs-time/)
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Write the tables, plots and report from the finished cells only; train nothing
    #[arg(long)]
    pub no_train: bool,
    /// Host memory for each cell's training-image cache, in GiB
    #[arg(long, value_parser = super::positive_f64, default_value_t = 8.0)]
    pub host_budget_gib: f64,
    /// Less output
    #[arg(long)]
    pub quiet: bool,
}

/// Simulates `scene` into `out/data` unless a finished simulation is there (written to a temporary folder first,
/// then renamed, so an interrupted simulation is never taken for a finished one).
fn builtin_data(scene: &str, out: &Path) -> anyhow::Result<PathBuf> {
    let data = out.join("data");
    if data.join("transforms.json").is_file() {
        return Ok(data);
    }
    let tmp = out.join(".data.tmp");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| anyhow::anyhow!("{}: {e}", tmp.display()))?;
    }
    let desc = crate::sim::SceneDesc::load(scene)?;
    let sim = crate::sim::simulate(&desc, &crate::sim::SimOptions::default(), &tmp)?;
    eprintln!("simulated `{scene}`: {sim}");
    if data.exists() {
        std::fs::remove_dir_all(&data).map_err(|e| anyhow::anyhow!("{}: {e}", data.display()))?;
    }
    std::fs::rename(&tmp, &data).map_err(|e| anyhow::anyhow!("{}: {e}", data.display()))?;
    Ok(data)
}

/// Today's date (UTC) as YYYY-MM-DD, from the system clock.
fn today() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    // Howard Hinnant's days-to-civil.
    let z = (secs / 86400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The command line as typed (binary name shortened to `msnerf`), for the report's "regenerate" line.
fn command_line() -> String {
    let args: Vec<String> =
        std::env::args().skip(1).map(|a| if a.contains([' ', '"', '\'']) { format!("'{a}'") } else { a }).collect();
    format!("msnerf {}", args.join(" "))
}

pub fn run(cli: &Cli, a: &SweepArgs) -> anyhow::Result<()> {
    let grid = Grid::load(&a.grid)?;
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let data = match (&a.data, &a.builtin_scene) {
        (Some(d), _) => d.clone(),
        (None, Some(scene)) => builtin_data(scene, &a.out)?,
        (None, None) => anyhow::bail!("give --data DIR or --builtin-scene NAME"),
    };
    let ds = crate::data::load_dataset(&data, &Default::default())?;
    let data_words = match &a.builtin_scene {
        Some(s) => format!(
            "the built-in simulated scene `{s}` ({}x{}, {} views, {} bands)",
            ds.width,
            ds.height,
            ds.frames.len(),
            ds.n_bands()
        ),
        None => format!(
            "`{}` ({}x{}, {} views, {} bands)",
            data.display(),
            ds.width,
            ds.height,
            ds.frames.len(),
            ds.n_bands()
        ),
    };
    let ctx = Context::new(&cli.context_desc())?;
    let opts = SweepOptions {
        data: data.clone(),
        out: a.out.clone(),
        host_budget_bytes: (a.host_budget_gib * (1u64 << 30) as f64) as u64,
        progress: !a.quiet,
    };
    let (results, failed) = if a.no_train {
        let results: Vec<_> = grid
            .cells
            .iter()
            .filter_map(|c| crate::sweep::run::done_result(&grid, &a.out, &crate::sweep::run::cell_id(&grid, c)))
            .collect();
        (results, Vec::new())
    } else {
        let o = run_sweep(&ctx, &grid, &opts)?;
        eprintln!(
            "{} cells: {} trained now, {} done before, {} failed",
            grid.cells.len(),
            o.trained.len(),
            o.skipped.len(),
            o.failed.len()
        );
        (o.results, o.failed)
    };
    let caps = ctx.caps();
    let machine = Machine {
        device: caps.name.clone(),
        device_type: caps.device_type.clone(),
        driver: format!("{} {}", caps.driver_name, caps.driver_info).trim().to_string(),
        cpu: Machine::host_cpu(),
        cpu_threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let mut written = write_tables(&grid, &machine, &data, &results, &a.out)?;
    written.extend(plots::write_plots(&results, &a.out.join("plots"))?);
    let mut rc = ReportContext {
        grid: &grid,
        machine: &machine,
        data: data_words,
        command: command_line(),
        plots_rel: "plots".into(),
        date: today(),
    };
    let report = a.out.join("report.md");
    atomic::write_bytes(&report, report_markdown(&rc, &results).as_bytes())?;
    written.push(report);
    if let Some(page) = &a.report {
        let dir = page.with_extension("");
        written.extend(plots::write_plots(&results, &dir)?);
        rc.plots_rel = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "plots".into());
        atomic::write_bytes(page, report_markdown(&rc, &results).as_bytes())?;
        written.push(page.clone());
    }
    if !a.quiet {
        for w in &written {
            println!("wrote {}", w.display());
        }
    }
    if !failed.is_empty() {
        let list: Vec<String> = failed.iter().map(|(_, e)| e.clone()).collect();
        anyhow::bail!("{} cell(s) failed (rerun to retry them):\n{}", failed.len(), list.join("\n"));
    }
    Ok(())
}
