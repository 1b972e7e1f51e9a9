//! The `msnerf` binary: parses the command line and runs the subcommand (see `msnerf::cli`).

use clap::Parser;

fn main() {
    let cli = msnerf::cli::Cli::parse();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level)).format_timestamp(None).init();
    if let Err(e) = msnerf::cli::run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
