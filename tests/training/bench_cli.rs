//! `msnerf bench kernels` and `msnerf bench train` through the CLI: the JSON names the device and carries every
//! figure the docs quote (wall-clock and timestamp throughput, the CPU sgemm comparison on a CPU device, the batch
//! and chunk sizes), and bad flags are refused with the flag's name.

use std::process::Command;

fn msnerf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_msnerf"))
}

fn json(args: &[&str]) -> serde_json::Value {
    let out = msnerf().args(args).output().expect("run msnerf");
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

#[test]
fn bench_kernels_reports_the_proposal_grid_and_mlp() {
    let v = json(&[
        "bench",
        "kernels",
        "--filter",
        "nerfacto proposal",
        "--points",
        "4096",
        "--rows",
        "2048",
        "--repeats",
        "1",
        "--json",
    ]);
    assert!(!v["device"].as_str().unwrap_or("").is_empty(), "device named: {v}");
    let hash = v["hash"].as_array().expect("hash");
    assert_eq!(hash.len(), 1, "the filter keeps the proposal grid only: {v}");
    assert!(hash[0]["forward_mpts_per_s"].as_f64().unwrap() > 0.0);
    let mlp = v["mlp"].as_array().expect("mlp");
    assert_eq!(mlp.len(), 1, "{v}");
    let m = &mlp[0];
    assert_eq!(m["shape"], "16-16-1");
    assert_eq!(m["rows"], 2048);
    for key in ["forward_gflops", "train_gflops", "train_kernel_gflops"] {
        assert!(m[key].as_f64().is_some_and(|g| g > 0.0), "{key}: {m}");
    }
    let kernels: Vec<&str> =
        m["train_kernels"].as_array().unwrap().iter().map(|k| k["name"].as_str().unwrap()).collect();
    for k in ["mlp_fwd", "mlp_bwd", "mlp_wgrad", "mlp_wgrad_reduce", "mlp_out_delta"] {
        assert!(kernels.contains(&k), "{k} timed: {kernels:?}");
    }
    // The device kind decides the kernel family and whether the CPU sgemm comparison is there.
    let is_cpu = m["cpu_sgemm_gflops"].as_f64().is_some();
    assert_eq!(m["shared_tiles"].as_bool(), Some(!is_cpu), "{m}");
    // The ratio comes from paired timings: present exactly when the sgemm is, positive.
    assert_eq!(m["sgemm_ratio"].as_f64().is_some_and(|r| r > 0.0), is_cpu, "{m}");
    // The texel-rows pairing runs on the register tiles only.
    assert_eq!(m["texel_rows_speedup"].as_f64().is_some_and(|r| r > 0.0), is_cpu, "{m}");
}

#[test]
fn bench_train_takes_the_batch_and_chunk_sizes() {
    let v = json(&[
        "bench",
        "train",
        "--models",
        "tiny",
        "--bands",
        "3",
        "--rays-per-batch",
        "48",
        "--rays-per-chunk",
        "32",
        "--steps",
        "12",
        "--json",
    ]);
    let rows = v.as_array().expect("one row per model and band count");
    assert_eq!(rows.len(), 1);
    let r = &rows[0];
    assert_eq!((r["model"].as_str(), r["bands"].as_u64()), (Some("tiny"), Some(3)));
    assert_eq!((r["rays_per_batch"].as_u64(), r["rays_per_chunk"].as_u64()), (Some(48), Some(32)));
    assert!(r["ms_per_step"].as_f64().is_some_and(|t| t > 0.0) && r["gpu_ms_per_step"].as_f64().is_some());
    // Steady state by default: past tiny's proposal warm-up (200 steps), one step in 5 updates the proposals.
    assert_eq!(r["first_step"].as_u64(), Some(201 + 2), "two untimed steps first: {r}");
    let updates = r["proposal_update_steps"].as_u64().unwrap();
    assert!((2..=3).contains(&updates), "12 steady steps update the proposals 2 or 3 times, got {updates}");
    // The host-time split. A step is one submission and one wait (issue 22), two chunks included: its rays go in
    // and its losses come out through the step's own host buffers, with no staging transfer of their own.
    let h = &r["host"];
    assert_eq!((h["submits"].as_u64(), h["waits"].as_u64()), (Some(1), Some(1)), "{h}");
    for k in ["record_ms", "submit_wait_ms"] {
        assert!(h[k].as_f64().is_some_and(|t| t > 0.0), "{k}: {h}");
    }
    for k in ["upload_ms", "readback_ms"] {
        assert_eq!(h[k].as_f64(), Some(0.0), "{k}: {h}");
    }
    assert_eq!(r["steps_in_flight"].as_u64(), Some(2), "the profile's default: {r}");
    assert!(r["ms_per_step_profiled"].as_f64().is_some_and(|t| t > 0.0), "{r}");
    assert!(r["device"].as_str().is_some_and(|d| !d.is_empty()), "the JSON names the device: {r}");
    let tiling = r["mlp_tiling"].as_str().unwrap_or_default();
    assert!(tiling.contains("coop_matrix") && tiling.contains("coop_layers"), "the JSON names the MLP kernels: {r}");
    assert!(r["sampling_ms_per_step"].as_f64().is_some_and(|t| t > 0.0), "{r}");
    let wall = r["ms_per_step"].as_f64().unwrap();
    let overhead = r["host_overhead_ms_per_step"].as_f64().unwrap();
    assert!((overhead - (wall - r["gpu_ms_per_step"].as_f64().unwrap())).abs() < 1e-9 && overhead < wall);
    let validation = std::env::var("MSNERF_REQUIRE_VALIDATION").is_ok_and(|v| v == "1");
    if validation {
        assert_eq!(r["validation"].as_bool(), Some(true), "the JSON says the layer was on");
    }
    // From step 0 every step updates the proposals (nerfstudio's first ten steps).
    let v = json(&[
        "bench",
        "train",
        "--models",
        "tiny",
        "--bands",
        "3",
        "--rays-per-batch",
        "48",
        "--steps",
        "4",
        "--at-step",
        "0",
        "--json",
    ]);
    assert_eq!(v[0]["proposal_update_steps"].as_u64(), Some(4), "{}", v[0]);
    let out = msnerf().args(["bench", "train", "--models", "tiny", "--rays-per-chunk", "0"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--rays-per-chunk"), "the error names the flag");
}

/// `MSNERF_RAY_LANES` picks the per-ray kernels of a whole training step (issue 22): forced on, lavapipe runs the
/// GPU variants and the per-kernel breakdown names them; off, the serial ones; a value other than 0 or 1 stops the
/// command with an error naming the variable.
#[test]
fn ray_lanes_switch_picks_the_per_ray_kernels_and_refuses_bad_values() {
    // From step 0, where every step updates the proposals: the interlevel loss runs too.
    let args: Vec<&str> =
        "bench train --models tiny --bands 3 --rays-per-batch 48 --steps 2 --at-step 0".split(' ').collect();
    let kernels = |lanes: &str| -> Vec<String> {
        let out = msnerf().args(&args).arg("--json").env("MSNERF_RAY_LANES", lanes).output().expect("run msnerf");
        assert!(out.status.success(), "MSNERF_RAY_LANES={lanes}: {}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
        v[0]["kernels"].as_array().expect("kernels").iter().map(|k| k["name"].as_str().unwrap().to_owned()).collect()
    };
    let on = kernels("1");
    for k in
        ["sample_initial_edges", "density_weights_lanes", "pdf_resample_lanes", "interlevel_lanes", "composite_lanes"]
    {
        assert!(on.iter().any(|n| n == k), "{k} runs with MSNERF_RAY_LANES=1: {on:?}");
    }
    let off = kernels("0");
    assert!(off.iter().all(|n| !n.ends_with("_lanes") && n != "sample_initial_edges"), "{off:?}");
    assert!(off.iter().any(|n| n == "density_weights"), "{off:?}");
    let out = msnerf().args(&args).env("MSNERF_RAY_LANES", "yes").output().expect("run msnerf");
    assert!(!out.status.success(), "a bad value is refused");
    assert!(String::from_utf8_lossy(&out.stderr).contains("MSNERF_RAY_LANES"), "the error names the variable");
}

/// `MSNERF_HASH_ONE_DISPATCH` picks how a whole training step records the hash grids' forward (issue 22): on, one
/// dispatch per grid and pass (the tiny profile's field and two proposal grids: 3 per step); off, one per level; a
/// value other than 0 or 1 stops the command with an error naming the variable.
#[test]
fn hash_one_dispatch_switch_records_one_forward_per_grid_and_refuses_bad_values() {
    let args: Vec<&str> =
        "bench train --models tiny --bands 3 --rays-per-batch 48 --steps 2 --at-step 0 --json".split(' ').collect();
    let forwards = |on: &str| -> u64 {
        let out = msnerf().args(&args).env("MSNERF_HASH_ONE_DISPATCH", on).output().expect("run msnerf");
        assert!(out.status.success(), "MSNERF_HASH_ONE_DISPATCH={on}: {}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
        let k = v[0]["kernels"].as_array().expect("kernels").iter().find(|k| k["name"] == "hashgrid_fwd").cloned();
        k.expect("hashgrid_fwd runs")["count"].as_u64().expect("count")
    };
    assert_eq!(forwards("1"), 2 * 3, "one forward per grid in each of the 2 steps");
    let per_level = forwards("0");
    assert!(per_level >= 2 * 3 * 2, "one forward per level: {per_level}");
    let out = msnerf().args(&args).env("MSNERF_HASH_ONE_DISPATCH", "2").output().expect("run msnerf");
    assert!(!out.status.success(), "a bad value is refused");
    assert!(String::from_utf8_lossy(&out.stderr).contains("MSNERF_HASH_ONE_DISPATCH"), "the error names the variable");
}

/// The compositing kernels hold per-band arrays of 128: 129 bands is refused when the pipeline is built, with the
/// count named, instead of writing past those arrays on the device; 128 trains.
#[test]
fn more_bands_than_the_renderer_takes_are_refused_by_count() {
    let run = |bands: &str| {
        let args = ["bench", "train", "--models", "tiny", "--bands", bands, "--rays-per-batch", "16", "--steps", "1"];
        msnerf().args(args).output().expect("run msnerf")
    };
    let out = run("129");
    assert!(!out.status.success(), "129 bands refused");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("129 bands") && err.contains("1 to 128"), "the error names the count and the limit: {err}");
    let out = run("128");
    assert!(out.status.success(), "128 bands train: {}", String::from_utf8_lossy(&out.stderr));
}

/// `tools/bench-vs-nerfstudio.sh` (issue 22): bad flags and a missing venv stop it with exit status 2 and a message
/// that names the flag or says what to do, before anything heavy runs. (The comparison itself needs nerfstudio and
/// minutes of CPU time: docs/benchmarks.md has its figures.)
#[test]
fn bench_vs_nerfstudio_refuses_bad_flags_and_a_missing_venv_by_name() {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/bench-vs-nerfstudio.sh");
    let run = |args: &[&str]| {
        let o = std::process::Command::new("bash")
            .arg(script)
            .args(args)
            .env("NS_VENV", "/nonexistent/ns-venv")
            .output()
            .expect("bash runs");
        (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (code, err) = run(&["--bogus"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("unknown flag: --bogus"), "{err}");
    let (code, err) = run(&["--steps", "0"]);
    assert!(code == Some(2) && err.contains("--steps needs a positive integer, got '0'"), "{err}");
    let (code, err) = run(&["--rays"]);
    assert!(code == Some(2) && err.contains("--rays needs a value"), "{err}");
    let (code, err) = run(&["--steps", "6"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("no Python venv at NS_VENV=/nonexistent/ns-venv") && err.contains("--install"), "{err}");
}
