//! Hardware profiles, the device's allocation rule, `msnerf plan` (table, JSON, --fit, non-zero exit when the plan
//! does not fit) and `msnerf train --hardware` (refuses before allocating, naming the largest chunk that fits;
//! trains with the profile's sizes when it fits).

use crate::common;
use common::gpu;
use msnerf::plan::hardware::HardwareProfile;
use msnerf::plan::{DeviceRule, Footprint};
use std::path::PathBuf;
use std::process::Command;

fn msnerf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_msnerf"))
}

fn tmp(tag: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("msnerf-plan-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(&p).unwrap();
    p
}

#[test]
fn profile_errors_name_the_file_and_the_key() {
    let dir = tmp("profiles");
    let good = include_str!("../../configs/hardware/lavapipe.yaml");
    let typo = dir.join("typo.yaml");
    std::fs::write(&typo, good.replace("headroom_gib: 0.5", "headroom_gb: 0.5")).unwrap();
    let e = HardwareProfile::resolve(typo.to_str().unwrap()).unwrap_err().to_string();
    assert!(e.contains("typo.yaml") && e.contains("headroom_gb"), "{e}");
    let bad = dir.join("bad.yaml");
    std::fs::write(&bad, good.replace("rays_per_chunk: 512", "rays_per_chunk: 0")).unwrap();
    let e = HardwareProfile::resolve(bad.to_str().unwrap()).unwrap_err().to_string();
    assert!(e.contains("bad.yaml") && e.contains("trainer.rays_per_chunk"), "{e}");
    let e = HardwareProfile::resolve("rtx9090").unwrap_err().to_string();
    assert!(e.contains("rtx9090") && e.contains("rtx2080ti-11gb"), "{e}");
    let p = HardwareProfile::resolve("rtx2080ti-11gb").unwrap();
    assert_eq!((p.trainer.rays_per_batch, p.trainer.eval_rays_per_chunk), (16384, 8192));
    let p = HardwareProfile::resolve("a100-80gb").unwrap();
    assert_eq!((p.trainer.rays_per_batch, p.trainer.eval_rays_per_chunk), (32768, 16384));
    let _ = std::fs::remove_dir_all(dir);
}

/// lavapipe's allocation rule, as the device reports it, against the documented rule the planner uses without a
/// device (round up to 256 B, at least 16 B): the rule never plans fewer bytes than the device reserves.
#[test]
fn device_footprints_and_the_documented_rule() {
    let g = gpu();
    let dev = DeviceRule::from_context(&g);
    let rule = DeviceRule { footprint: Footprint::Rule { align: 256, min: 16 }, ..dev.clone() };
    let mut seen = Vec::new();
    for size in [0u64, 1, 4, 15, 16, 17, 63, 64, 65, 255, 256, 257, 1000, 4096, 1 << 20, (1 << 20) + 4] {
        let d = dev.bytes(size);
        assert!(d >= size.max(1), "footprint of {size} is {d}");
        assert!(rule.bytes(size) >= d, "the rule plans fewer bytes than the device reserves for {size}");
        seen.push(format!("{size}->{d}"));
    }
    eprintln!("{}: {}", g.caps().name, seen.join(" "));
}

#[test]
fn plan_prints_every_part_json_and_fit() {
    let out = msnerf().args(["plan", "--hardware", "rtx2080ti-11gb", "--no-device"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}\n{}", String::from_utf8_lossy(&out.stderr));
    for part in [
        "parameter store",
        "hash-grid level tables",
        "camera table",
        "training chunk",
        "evaluation chunk",
        "staging",
        "NaN/Inf guard flag",
        "proposal 1 MLP activations",
        "nerf MLP activations",
        "colour MLP deltas",
        "adam v[chunk 0]",
        "N = 4000 resident",
    ] {
        assert!(text.contains(part), "missing {part:?} in\n{text}");
    }
    let out = msnerf()
        .args(["plan", "--hardware", "a100-80gb", "--no-device", "--json", "--fit", "--views", "100", "--bands", "4"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let total = v["vram"]["total_bytes"].as_u64().unwrap();
    let sum: u64 = v["vram"]["entries"].as_array().unwrap().iter().map(|e| e["bytes"].as_u64().unwrap()).sum();
    assert_eq!(total, sum);
    assert_eq!(v["vram"]["bands"], 4);
    assert_eq!(v["data"]["n_frames"], 100);
    let fit = v["fit"]["max_rays_per_chunk"].as_u64().unwrap();
    assert!(fit >= 32768 && fit % 128 == 0, "{fit}");
}

#[test]
fn plan_that_does_not_fit_exits_non_zero() {
    let out = msnerf()
        .args([
            "plan",
            "--hardware",
            "rtx2080ti-11gb",
            "--no-device",
            "--rays-per-batch",
            "32768",
            "--rays-per-chunk",
            "32768",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("does not fit") && err.contains("VRAM"), "{err}");
    // A host budget too small for one image.
    let out = msnerf()
        .args([
            "plan",
            "--hardware",
            "lavapipe",
            "--model",
            "tiny",
            "--width",
            "20000",
            "--height",
            "20000",
            "--no-device",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("host memory"));
}

fn small_dataset(dir: &std::path::Path) -> PathBuf {
    let scene = msnerf::sim::SceneDesc::load("ci-small").unwrap();
    let opts = msnerf::sim::SimOptions {
        width: Some(32),
        height: Some(24),
        views: Some(6),
        points: 1000,
        ..Default::default()
    };
    let data = dir.join("data");
    msnerf::sim::simulate(&scene, &opts, &data).unwrap();
    data
}

#[test]
fn train_with_hardware_refuses_or_trains_with_the_profile() {
    let dir = tmp("train");
    let data = small_dataset(&dir);
    // Table 1's model at 4096 rays in one pass needs more than lavapipe's budget and larger bindings.
    let out = msnerf()
        .args([
            "train",
            "--quiet",
            "--model",
            "multispectral-nerf",
            "--hardware",
            "lavapipe",
            "--rays-per-batch",
            "4096",
            "--rays-per-chunk",
            "4096",
        ])
        .arg("--data")
        .arg(&data)
        .arg("--out")
        .arg(dir.join("run-big"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("does not fit lavapipe") && err.contains("--rays-per-chunk"), "{err}");
    assert!(!dir.join("run-big/checkpoints").exists(), "refused before training");
    // The tiny model with the lavapipe profile trains two steps.
    let out = msnerf()
        .args([
            "train",
            "--quiet",
            "--model",
            "tiny",
            "--hardware",
            "lavapipe",
            "--max-steps",
            "2",
            "--eval-pixels",
            "64",
        ])
        .arg("--data")
        .arg(&data)
        .arg("--out")
        .arg(dir.join("run-tiny"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("hardware lavapipe: 512 rays per batch in chunks of 512"), "{err}");
    let _ = std::fs::remove_dir_all(dir);
}
