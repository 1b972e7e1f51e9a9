//! The `msnerf` binary: parses the command line and runs the subcommand (see `msnerf::cli`).

use clap::Parser;

fn main() {
    // Output piped into a reader that closes early (`msnerf ... | head`) ends the process quietly, as other Unix
    // tools do, instead of a panic in `println!` (Rust ignores SIGPIPE by default). Sockets are unaffected: the
    // standard library sends with MSG_NOSIGNAL.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to its default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
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
