//! `msnerf bench kernels|train|import`: prints a benchmark table (or `--json`). See `msnerf::bench`.

use super::Cli;
use crate::gpu::Context;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchWhat {
    /// A processed raw flight against the simulator's truth: captures, CRS, reflectance, registration, cloud and
    /// DSM (datum shift removed), held-out PSNR, stage times and memory (`make flight-acceptance`)
    Flight {
        /// The simulated flight's folder (`simulate --raw-rig --out`: card/ and truth/)
        #[arg(long)]
        flight: PathBuf,
        /// The project `msnerf process` made of its card
        #[arg(long)]
        project: PathBuf,
        /// A run trained on the flight's truth/dataset, and the folder of its cloud.las and dsm.tif
        #[arg(long, requires = "direct_products")]
        direct_run: Option<PathBuf>,
        #[arg(long, requires = "direct_run")]
        direct_products: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Training-step time, rays/s and per-kernel breakdown for model profiles at several band counts
    Train {
        /// Model profiles (built-in names or YAML files), comma separated
        #[arg(long, value_delimiter = ',', default_value = "nerfacto,multispectral-nerf")]
        models: Vec<String>,
        /// Band counts, comma separated
        #[arg(long, value_delimiter = ',', default_value = "3,6,16,64")]
        bands: Vec<usize>,
        /// Rays per batch (overrides the profile; keeps lavapipe runs short)
        #[arg(long)]
        rays_per_batch: Option<usize>,
        /// Rays per GPU pass within a batch (overrides the profile; at most the batch)
        #[arg(long)]
        rays_per_chunk: Option<usize>,
        /// Timed steps (after 2 untimed ones)
        #[arg(long, default_value_t = 20)]
        steps: usize,
        /// Pipeline step to start at (default: the steady state past the proposal warm-up and annealing; 0 times the
        /// first steps of a run, where every step updates the proposals)
        #[arg(long)]
        at_step: Option<u64>,
        /// Steps submitted before the host waits for the oldest, comma separated to compare (default: the
        /// profile's `trainer.steps_in_flight`)
        #[arg(long, value_delimiter = ',')]
        steps_in_flight: Vec<usize>,
        #[arg(long)]
        json: bool,
    },
    /// Raw rig import speed (`import rig`): stage times of one capture, whole imports in both registration modes
    Import {
        /// A flight folder of raw rig TIFFs
        dir: std::path::PathBuf,
        /// Copies of the folder's captures to import (new capture ids), so one capture can stand for a flight
        #[arg(long, default_value_t = 1)]
        replicate: usize,
        /// Worker threads (default: all cores)
        #[arg(long)]
        threads: Option<usize>,
        #[arg(long)]
        json: bool,
    },
    /// Hash grid points/s and MLP GFLOP/s at nerfacto's and Table 1's sizes
    Kernels {
        /// Points per hash grid measurement
        #[arg(long, default_value_t = 1 << 18)]
        points: usize,
        /// Rows per MLP measurement
        #[arg(long, default_value_t = 1 << 16)]
        rows: usize,
        /// Timed repetitions (the median is reported)
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Print JSON instead of a table
        #[arg(long)]
        json: bool,
        /// Only the measurements whose name contains this
        #[arg(long)]
        filter: Option<String>,
    },
}

pub fn run(cli: &Cli, args: &BenchArgs) -> anyhow::Result<()> {
    if let BenchWhat::Flight { ref flight, ref project, ref direct_run, ref direct_products, json } = args.what {
        let direct = direct_run.as_deref().zip(direct_products.as_deref());
        let r = crate::bench::flight::flight_acceptance(flight, project, direct)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&r)?);
        } else {
            print!("{}", r.table());
        }
        return Ok(());
    }
    if let BenchWhat::Import { ref dir, replicate, threads, json } = args.what {
        let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
        let r = crate::bench::import::run(dir, replicate, threads)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&r)?);
        } else {
            print!("{}", r.table());
        }
        return Ok(());
    }
    let ctx = Context::new(&cli.context_desc())?;
    match args.what {
        BenchWhat::Train {
            ref models,
            ref bands,
            rays_per_batch,
            rays_per_chunk,
            steps,
            at_step,
            ref steps_in_flight,
            json,
        } => {
            anyhow::ensure!(steps > 0, "--steps must be > 0");
            if let Some(k) = steps_in_flight.iter().find(|k| !(1..=3).contains(*k)) {
                anyhow::bail!("--steps-in-flight must be 1, 2 or 3, got {k}");
            }
            let mut all = Vec::new();
            for m in models {
                let mut cfg = crate::nerf::config::ModelConfig::resolve(m)?;
                if let Some(r) = rays_per_batch {
                    cfg.trainer.set_rays_per_batch(r);
                }
                if let Some(c) = rays_per_chunk {
                    if c == 0 {
                        anyhow::bail!("--rays-per-chunk must be > 0");
                    }
                    cfg.trainer.set_rays_per_chunk(c);
                }
                let depths = if steps_in_flight.is_empty() {
                    vec![cfg.trainer.steps_in_flight]
                } else {
                    steps_in_flight.clone()
                };
                for &b in bands {
                    for &k in &depths {
                        cfg.trainer.steps_in_flight = k;
                        let r = crate::bench::train::run(&ctx, &cfg, b, steps, 2, at_step)?;
                        if !json {
                            print!("{}", r.table());
                        }
                        all.push(r);
                    }
                }
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&all)?);
            }
        }
        BenchWhat::Import { .. } | BenchWhat::Flight { .. } => unreachable!("handled above"),
        BenchWhat::Kernels { points, rows, repeats, json, ref filter } => {
            let r = crate::bench::kernels::run(&ctx, points, rows, repeats, filter.as_deref())?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                print!("{}", r.table());
            }
        }
    }
    Ok(())
}
