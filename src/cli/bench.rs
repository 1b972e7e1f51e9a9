//! `msnerf bench kernels`: prints the kernel benchmark table (or `--json`). See `msnerf::bench::kernels`.

use super::Cli;
use crate::gpu::Context;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchWhat {
    /// Hash grid points/s and fused MLP GFLOP/s at nerfacto's and Table 1's sizes
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
    let ctx = Context::new(&cli.context_desc())?;
    match args.what {
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
