//! The sweep's measurements as files: `cells.csv` (one row per configuration), `points.csv` (one row per
//! configuration, evaluation point and band, plus a `mean` row), `kernels.csv` (ms per step per kernel) and
//! `sweep.json` (the grid, the device and every result). All written atomically.
//!
//! The CSV is written by hand: three flat tables of numbers and identifiers, where RFC 4180 quoting is a few lines
//! and a dependency would buy nothing (the tests read the files back with the `csv` crate).

use super::error::SweepError;
use super::grid::Grid;
use super::pareto::{memory_front, time_front_cells};
use super::result::CellResult;
use crate::util::atomic;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// One CSV field: quoted when it holds a comma, a quote or a line break (quotes doubled).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.6}").trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        String::new()
    }
}

fn csv_text(header: &[String], rows: &[Vec<String>]) -> String {
    let line = |r: &[String]| r.iter().map(|f| csv_field(f)).collect::<Vec<_>>().join(",") + "\n";
    std::iter::once(line(header)).chain(rows.iter().map(|r| line(r))).collect()
}

/// `cells.csv`: settings, cost and accuracy of every configuration.
pub fn cells_csv(results: &[CellResult]) -> String {
    let keys: Vec<String> = {
        let mut k: Vec<String> = Vec::new();
        for r in results {
            for (key, _) in &r.values {
                if !k.contains(key) {
                    k.push(key.clone());
                }
            }
        }
        k
    };
    let front = time_front_cells(results);
    let mem_front = memory_front(results);
    let mut header: Vec<String> = ["index", "id", "profile", "band_names"].map(String::from).to_vec();
    header.extend(keys.iter().cloned());
    header.extend(
        [
            "steps",
            "train_s",
            "ms_per_step",
            "gpu_ms_per_step",
            "parameters",
            "peak_gpu_mib",
            "peak_cache_mib",
            "final_psnr",
            "final_ssim",
            "best_psnr",
            "trainer_best_eval_psnr",
            "on_time_front",
            "on_memory_front",
            "stopped",
            "depth_median_abs_m",
            "depth_bias_m",
            "depth_bias_footprints",
            "depth_within_1_footprint",
            "cloud_points",
            "cloud_accuracy_median_m",
            "cloud_completeness_median_m",
            "cloud_f_score",
            "cloud_rmse_planar_m",
            "cloud_rmse_vertical_m",
            "cloud_median_signed_dz_m",
            "standard_pass",
        ]
        .map(String::from),
    );
    let rows: Vec<Vec<String>> = results
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let f = r.final_point();
            let best = r.points.iter().map(|p| p.psnr).fold(f64::NAN, f64::max);
            let mut row = vec![r.index.to_string(), r.id.clone(), r.model.clone(), r.band_names.join(" ")];
            row.extend(
                keys.iter()
                    .map(|k| r.values.iter().find(|(kk, _)| kk == k).map(|(_, v)| v.clone()).unwrap_or_default()),
            );
            row.extend([
                r.steps.to_string(),
                num(r.elapsed_s),
                num(r.mean_step_ms),
                num(r.gpu_ms_per_step),
                r.parameters.to_string(),
                num(r.peak_gpu_bytes as f64 / 1048576.0),
                num(r.peak_cache_bytes as f64 / 1048576.0),
                f.map_or(String::new(), |p| num(p.psnr)),
                f.map_or(String::new(), |p| num(p.ssim)),
                num(best),
                r.trainer_best_eval_psnr.map_or(String::new(), num),
                front.contains(&i).to_string(),
                mem_front.contains(&i).to_string(),
                r.stopped.clone(),
            ]);
            // Geometry of the final point (empty when the dataset has no depth maps or ground-truth cloud).
            let g = f.and_then(|p| p.geometry.clone()).unwrap_or_default();
            let o = |v: Option<f64>| v.map_or(String::new(), num);
            row.extend([
                o(g.depth_median_abs_m),
                o(g.depth_bias_m),
                o(g.depth_bias_footprints),
                o(g.depth_within_one_footprint),
                g.cloud_points.map_or(String::new(), |n| n.to_string()),
                o(g.cloud_accuracy_median_m),
                o(g.cloud_completeness_median_m),
                o(g.cloud_f_score),
                o(g.cloud_rmse_planar_m),
                o(g.cloud_rmse_vertical_m),
                o(g.cloud_median_signed_dz_m),
                g.standard_pass.map_or(String::new(), |b| b.to_string()),
            ]);
            row
        })
        .collect();
    csv_text(&header, &rows)
}

/// `points.csv`: held-out PSNR/SSIM per configuration, evaluation point and band.
pub fn points_csv(results: &[CellResult]) -> String {
    let header = ["index", "id", "target_s", "train_s", "step", "band", "psnr", "ssim"].map(String::from).to_vec();
    let mut rows = Vec::new();
    for r in results {
        for p in &r.points {
            let lead = [r.index.to_string(), r.id.clone(), num(p.target_s), num(p.elapsed_s), p.step.to_string()];
            let mut row = lead.to_vec();
            row.extend(["mean".into(), num(p.psnr), num(p.ssim)]);
            rows.push(row);
            for b in &p.bands {
                let mut row = lead.to_vec();
                row.extend([b.name.clone(), num(b.psnr), num(b.ssim)]);
                rows.push(row);
            }
        }
    }
    csv_text(&header, &rows)
}

/// `kernels.csv`: mean ms and calls per training step of every kernel of every configuration.
pub fn kernels_csv(results: &[CellResult]) -> String {
    let header = ["index", "id", "kernel", "calls_per_step", "ms_per_step"].map(String::from).to_vec();
    let rows: Vec<Vec<String>> = results
        .iter()
        .flat_map(|r| {
            r.kernels.iter().map(move |k| {
                vec![r.index.to_string(), r.id.clone(), k.name.clone(), num(k.calls_per_step), num(k.ms_per_step)]
            })
        })
        .collect();
    csv_text(&header, &rows)
}

/// The machine a sweep ran on, as the report states it.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    pub device: String,
    pub device_type: String,
    pub driver: String,
    /// The host CPU (`model name` of /proc/cpuinfo where there is one).
    pub cpu: Option<String>,
    pub cpu_threads: usize,
}

impl Machine {
    /// This host's CPU model name, on Linux.
    pub fn host_cpu() -> Option<String> {
        let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
        let line = info.lines().find(|l| l.starts_with("model name"))?;
        Some(line.split_once(':')?.1.trim().to_string())
    }
}

#[derive(Serialize)]
struct SweepJson<'a> {
    grid: &'a Grid,
    machine: &'a Machine,
    data: &'a Path,
    cells: &'a [CellResult],
    time_front: Vec<String>,
}

/// Writes `cells.csv`, `points.csv`, `kernels.csv` and `sweep.json` into `out`; returns the paths.
pub fn write_tables(
    grid: &Grid,
    machine: &Machine,
    data: &Path,
    results: &[CellResult],
    out: &Path,
) -> Result<Vec<PathBuf>, SweepError> {
    let json = SweepJson {
        grid,
        machine,
        data,
        cells: results,
        time_front: time_front_cells(results).into_iter().map(|i| results[i].id.clone()).collect(),
    };
    let files = [
        ("cells.csv", cells_csv(results)),
        ("points.csv", points_csv(results)),
        ("kernels.csv", kernels_csv(results)),
        ("sweep.json", serde_json::to_string_pretty(&json).expect("the sweep table serialises")),
    ];
    let mut paths = Vec::new();
    for (name, text) in files {
        let p = out.join(name);
        atomic::write_bytes(&p, text.as_bytes())?;
        paths.push(p);
    }
    Ok(paths)
}
