//! Cache benchmark: `cargo run --release --example bench_cache [frames] [width] [height] [bands] [budget_MB]`.

use msnerf::data::bench::run_cache_bench;
use msnerf::data::synth::SynthSpec;

fn main() {
    let a: Vec<u64> = std::env::args().skip(1).filter_map(|s| s.parse().ok()).collect();
    let get = |i: usize, d: u64| a.get(i).copied().unwrap_or(d);
    let spec = SynthSpec {
        frames: get(0, 64) as usize,
        width: get(1, 1280) as u32,
        height: get(2, 960) as u32,
        bands: get(3, 6) as usize,
    };
    let budget = get(4, 256) * 1_000_000;
    match run_cache_bench(None, spec, budget, 200, 50) {
        Ok(r) => println!("{r:?}"),
        Err(e) => {
            eprintln!("bench failed: {e}");
            std::process::exit(1);
        }
    }
}
