//! The markdown report of a sweep: where it ran, which configuration to pick for a time budget (1, 5 and 15
//! minutes and the sweep's own evaluation points), the Pareto front, every configuration's cost and accuracy per
//! band, where the step time goes, the plots, and the limits of the measurement.

use super::grid::Grid;
use super::noise::{seed_noise, SeedNoise, SEED_KEY};
use super::pareto::{candidates, time_front, time_front_cells};
use super::result::{CellResult, TimePoint};
use super::table::Machine;
use std::fmt::Write;

/// What the report needs besides the results.
pub struct ReportContext<'a> {
    pub grid: &'a Grid,
    pub machine: &'a Machine,
    /// What was trained on, in words (`the built-in scene campus`, a dataset path).
    pub data: String,
    /// The command that regenerates this report.
    pub command: String,
    /// Folder of the plots relative to the report (`plots`).
    pub plots_rel: String,
    pub date: String,
}

/// The budgets the recommendation table answers: 1, 5 and 15 minutes and the sweep's own points, in seconds.
pub fn report_budgets(grid: &Grid) -> Vec<f64> {
    let mut b: Vec<f64> =
        grid.eval_at_s.iter().copied().chain(grid.budget.time_s).chain([60.0, 300.0, 900.0]).collect();
    b.sort_by(f64::total_cmp);
    b.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    b
}

/// The configuration with the best held-out PSNR measured at or before `budget_s` seconds of training, among those
/// trained on every band ([`candidates`]): (position in `results`, the point).
pub fn recommend(results: &[CellResult], budget_s: f64) -> Option<(usize, &TimePoint)> {
    let ok = candidates(results);
    results
        .iter()
        .enumerate()
        .filter(|(i, _)| ok[*i])
        .filter_map(|(i, r)| r.best_within(budget_s).map(|p| (i, p)))
        .max_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr).then(b.0.cmp(&a.0)))
}

/// PSNR (data range 1) of the mean squared error over the named bands of a point: each band's MSE is recovered from
/// its PSNR. NaN when a band is missing.
pub fn shared_psnr(p: &TimePoint, bands: &[&String]) -> f64 {
    let mse: Option<Vec<f64>> =
        bands.iter().map(|b| p.bands.iter().find(|x| &&x.name == b).map(|x| 10f64.powf(-x.psnr / 10.0))).collect();
    match mse {
        Some(m) if !m.is_empty() => -10.0 * (m.iter().sum::<f64>() / m.len() as f64).log10(),
        _ => f64::NAN,
    }
}

/// The other candidates whose best PSNR by `budget_s` is within `noise_db` (the measured seed noise) of the pick's.
fn near_ties(results: &[CellResult], budget_s: f64, pick: usize, psnr: f64, noise_db: f64) -> Vec<String> {
    let ok = candidates(results);
    results
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != pick && ok[*i])
        .filter_map(|(_, r)| {
            r.best_within(budget_s).filter(|p| psnr - p.psnr <= noise_db).map(|_| format!("#{}", r.index))
        })
        .collect()
}

/// The Limits section's line on seed noise: measured from repeats, or said to be unmeasured.
fn noise_line(results: &[CellResult], noise: Option<&SeedNoise>) -> String {
    let Some(n) = noise else {
        return format!(
            "- One run per configuration and one seed. Seed noise is not measured in this sweep (repeat a cell with \
             other `{SEED_KEY}` values to measure it), so no difference is called a tie; at a fixed wall-clock time \
             the machine's load adds more."
        );
    };
    let label = |i: usize| results.iter().find(|r| r.index == i).map_or(String::new(), |r| r.label.clone());
    let steps = |i: usize| results.iter().find(|r| r.index == i).map_or(0, |r| r.steps);
    let cells: Vec<String> = n.cells.iter().map(|&i| format!("#{i} ({}, {} steps)", label(i), steps(i))).collect();
    let spread: Vec<String> = n.spread_db.iter().map(|&(t, d)| format!("{d:.2} dB at {}", secs(t))).collect();
    format!(
        "- Seed noise, measured: {} are one configuration with other seeds; their held-out PSNR spread (max - min) \
         is {}. A difference smaller than the spread at the same evaluation point is called a tie. Under a wall-clock \
         budget the spread includes the machine's load as well as the seed: compare the repeats' step counts.",
        cells.join(", "),
        if spread.is_empty() { "not comparable (no shared evaluation point)".to_owned() } else { spread.join(", ") },
    )
}

fn secs(t: f64) -> String {
    if t >= 60.0 && (t / 60.0 - (t / 60.0).round()).abs() < 1e-9 {
        format!("{} min", (t / 60.0).round())
    } else {
        format!("{t:.0} s")
    }
}

fn db(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2}")
    } else {
        "–".into()
    }
}

fn mib(b: u64) -> String {
    format!("{:.1}", b as f64 / 1048576.0)
}

/// The whole report as markdown.
pub fn report_markdown(ctx: &ReportContext, results: &[CellResult]) -> String {
    let g = ctx.grid;
    let mut s = String::new();
    let noise = seed_noise(results);
    let _ = writeln!(s, "# Accuracy against training time: `{}`\n", g.name);
    if let Some(d) = &g.description {
        let _ = writeln!(s, "{}\n", d.trim());
    }
    let budget = match (g.budget.time_s, g.budget.steps) {
        (Some(t), Some(n)) => format!("{} of training time or {n} steps, whichever comes first", secs(t)),
        (Some(t), None) => format!("{} of training time", secs(t)),
        (None, Some(n)) => format!("{n} steps"),
        (None, None) => "no budget".into(),
    };
    let m = ctx.machine;
    let _ = writeln!(
        s,
        "**Measured on** {} ({}, driver {}), host CPU {}{} threads, {}. **Data:** {}. **Grid:** `{}` ({} configurations).\n",
        m.device,
        m.device_type,
        m.driver,
        m.cpu.as_deref().map(|c| format!("{c}, ")).unwrap_or_default(),
        m.cpu_threads,
        ctx.date,
        ctx.data,
        g.source,
        results.len()
    );
    let _ = writeln!(s, "**Regenerate:** `{}`\n", ctx.command);
    let points: Vec<String> = g.eval_at_s.iter().map(|t| secs(*t)).collect();
    let _ = writeln!(
        s,
        "Each configuration is trained from scratch, with the same seed (unless a cell sets `trainer.seed`), for {budget}. \
         Held-out PSNR (data range 1, the \
         MSE over all bands) and SSIM are measured on {} whole held-out views after {} of training{}; evaluation \
         time is not counted as training time. Time per step is the host time of one training step; the per-kernel \
         split comes from GPU timestamps.\n",
        g.eval_views,
        if points.is_empty() { "the end".to_string() } else { points.join(", ") },
        if points.is_empty() || g.eval_at_s.last().copied() == g.budget.time_s { "" } else { " and at the end of the budget" },
    );

    let _ = writeln!(s, "## What to pick for a time budget\n");
    let max_t = results.iter().flat_map(|r| r.points.iter().map(|p| p.target_s)).fold(0.0, f64::max);
    let _ = writeln!(
        s,
        "| budget | pick | held-out PSNR (dB) | SSIM | steps | note |\n| --- | --- | ---: | ---: | ---: | --- |"
    );
    for b in report_budgets(g) {
        match recommend(results, b) {
            Some((i, p)) => {
                let r = &results[i];
                let mut note = if b > max_t + 1e-9 {
                    format!(
                        "not measured past {}: the best at {} (longer training will do better)",
                        secs(max_t),
                        secs(p.target_s)
                    )
                } else {
                    format!("measured at {:.0} s", p.elapsed_s)
                };
                if let Some(n) = &noise {
                    let threshold = n.at(p.target_s);
                    let close = near_ties(results, b, i, p.psnr, threshold);
                    if !close.is_empty() {
                        let _ = write!(note, "; within the seed noise ({threshold:.2} dB): {}", close.join(", "));
                    }
                }
                let _ = writeln!(
                    s,
                    "| {} | #{} {} | {} | {:.3} | {} | {note} |",
                    secs(b),
                    r.index,
                    r.label,
                    db(p.psnr),
                    p.ssim,
                    p.step
                );
            }
            None => {
                let _ = writeln!(s, "| {} | – | – | – | – | nothing was evaluated this early |", secs(b));
            }
        }
    }

    let left_out: Vec<String> =
        results.iter().zip(candidates(results)).filter(|(_, c)| !c).map(|(r, _)| format!("#{}", r.index)).collect();
    if !left_out.is_empty() {
        let _ = writeln!(
            s,
            "\nOnly configurations trained on every band are picked here and on the fronts: {} trained on fewer \
             bands, so they produce no others and their PSNR averages a different set of bands; they are compared \
             per band below.",
            left_out.join(", ")
        );
    }
    let _ = writeln!(s, "\n## Pareto front: held-out PSNR against training time\n");
    let _ = writeln!(
        s,
        "The points no other measurement beats on both counts (less time and higher PSNR): for any time on the \
         front, nothing in this sweep did better sooner.\n"
    );
    let _ = writeln!(s, "| training time | configuration | held-out PSNR (dB) | steps |\n| ---: | --- | ---: | ---: |");
    for (ci, pi) in time_front(results) {
        let (r, p) = (&results[ci], &results[ci].points[pi]);
        let _ = writeln!(s, "| {:.0} s | #{} {} | {} | {} |", p.target_s, r.index, r.label, db(p.psnr), p.step);
    }

    let _ = writeln!(s, "\n## Every configuration\n");
    let front = time_front_cells(results);
    let mut head =
        "| # | settings | model | bands | steps | ms/step | parameters | peak GPU MiB | cache MiB |".to_string();
    let mut rule = "| ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |".to_string();
    let targets: Vec<f64> = {
        let mut t: Vec<f64> = results.iter().flat_map(|r| r.points.iter().map(|p| p.target_s)).collect();
        t.sort_by(f64::total_cmp);
        t.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        t
    };
    for t in &targets {
        let _ = write!(head, " PSNR @ {} |", secs(*t));
        rule += " ---: |";
    }
    let _ = writeln!(s, "{head} final SSIM |\n{rule} ---: |");
    for (i, r) in results.iter().enumerate() {
        let mut row = format!(
            "| {}{} | {} | {} | {} | {} | {:.0} | {} | {} | {} |",
            r.index,
            if front.contains(&i) { " ★" } else { "" },
            r.label,
            r.model,
            r.band_names.len(),
            r.steps,
            r.mean_step_ms,
            r.parameters,
            mib(r.peak_gpu_bytes),
            mib(r.peak_cache_bytes)
        );
        for t in &targets {
            let v = r.points.iter().find(|p| (p.target_s - t).abs() < 1e-9).map_or(f64::NAN, |p| p.psnr);
            let _ = write!(row, " {} |", db(v));
        }
        let _ = writeln!(s, "{row} {} |", r.final_point().map_or("–".into(), |p| format!("{:.3}", p.ssim)));
    }
    let _ = writeln!(s, "\n★: on the PSNR-against-time Pareto front at some point.\n");

    // Per band, at the end of the budget; a band a configuration did not train on is blank.
    let mut bands: Vec<String> = Vec::new();
    for r in results {
        for b in &r.band_names {
            if !bands.contains(b) {
                bands.push(b.clone());
            }
        }
    }
    let _ = writeln!(s, "## Held-out PSNR per band at the end of the budget (dB)\n");
    let shared: Vec<&String> = bands.iter().filter(|b| results.iter().all(|r| r.band_names.contains(b))).collect();
    if shared.len() < bands.len() {
        let _ = writeln!(
            s,
            "The configurations train on different bands, so their all-band PSNRs average different things: compare \
             the bands they share ({}).\n",
            shared.iter().map(|b| b.as_str()).collect::<Vec<_>>().join(", ")
        );
    }
    let with_shared = !shared.is_empty() && shared.len() < bands.len();
    let (extra_head, extra_rule) = if with_shared { (" shared bands |", " ---: |") } else { ("", "") };
    let _ =
        writeln!(s, "| # | {} |{extra_head}\n| ---: |{}{extra_rule}", bands.join(" | "), " ---: |".repeat(bands.len()));
    for r in results {
        let f = r.final_point();
        let cells: Vec<String> = bands
            .iter()
            .map(|b| f.and_then(|p| p.bands.iter().find(|x| &x.name == b)).map_or(String::new(), |x| db(x.psnr)))
            .collect();
        let extra = match (with_shared, f) {
            (true, Some(p)) => format!(" {} |", db(shared_psnr(p, &shared))),
            _ => String::new(),
        };
        let _ = writeln!(s, "| {} | {} |{extra}", r.index, cells.join(" | "));
    }
    if with_shared {
        let _ =
            writeln!(s, "\nshared bands: the PSNR of the mean squared error over the bands every configuration has.");
    }

    geometry_section(&mut s, results);

    let _ = writeln!(s, "\n## Where a training step's time goes (GPU ms per step)\n");
    let mut kernels: Vec<String> = Vec::new();
    for r in results {
        for k in r.kernels.iter().take(5) {
            if !kernels.contains(&k.name) {
                kernels.push(k.name.clone());
            }
        }
    }
    let _ = writeln!(
        s,
        "| # | host ms/step | GPU ms/step | {} |\n| ---: | ---: | ---: |{}",
        kernels.join(" | "),
        " ---: |".repeat(kernels.len())
    );
    for r in results {
        let ks: Vec<String> = kernels
            .iter()
            .map(|k| r.kernels.iter().find(|x| &x.name == k).map_or(String::new(), |x| format!("{:.1}", x.ms_per_step)))
            .collect();
        let _ = writeln!(s, "| {} | {:.0} | {:.0} | {} |", r.index, r.mean_step_ms, r.gpu_ms_per_step, ks.join(" | "));
    }
    let _ = writeln!(s, "\nEvery kernel of every configuration: `kernels.csv` in the sweep's output folder.\n");

    let p = &ctx.plots_rel;
    let _ = writeln!(s, "## Plots\n");
    for (stem, what) in [
        (
            "psnr_vs_time",
            "Held-out PSNR against training time; black rings: the Pareto front of the models of every band.",
        ),
        ("kernel_times", "GPU time per training step, stacked by kernel."),
        (
            "memory_vs_psnr",
            "Final held-out PSNR against peak GPU memory; black rings: the Pareto front of the models of every band.",
        ),
    ] {
        let _ = writeln!(s, "![{what}]({p}/{stem}.svg)\n\n{what} ([PNG]({p}/{stem}.png))\n");
    }

    let _ = writeln!(s, "## Limits\n");
    if let Some(n) = &g.notes {
        let _ = writeln!(s, "{}\n", n.trim());
    }
    let _ = writeln!(
        s,
        "{}\n\
         - Wall-clock budgets measure this machine under its load at the time; steps per second move with it.\n\
         - PSNR is over {} held-out views, not the whole eval split (`msnerf eval RUN` scores them all).",
        noise_line(results, noise.as_ref()),
        g.eval_views
    );
    if m.device_type.eq_ignore_ascii_case("cpu") {
        let _ = writeln!(
            s,
            "- The device is a CPU Vulkan driver: its timestamps measure CPU time, so the kernel split shows where \
             the CPU goes, not what a GPU would spend."
        );
    }
    s
}

/// "Geometry at each evaluation point": depth and cloud accuracy against time, when the cells measured them (a
/// dataset with depth maps and the simulator's `ground_truth.ply`); nothing otherwise.
fn geometry_section(s: &mut String, results: &[CellResult]) {
    if !results.iter().any(|r| r.points.iter().any(|p| p.geometry.is_some())) {
        return;
    }
    let o = |v: Option<f64>, p: usize| v.map_or(String::new(), |x| format!("{x:.p$}"));
    let pct = |v: Option<f64>| v.map_or(String::new(), |x| format!("{:.0} %", 100.0 * x));
    let _ = writeln!(s, "\n## Geometry at each evaluation point\n");
    let _ = writeln!(
        s,
        "Held-out median depth against the depth maps (bias + = in front of the surface, in metres and pixel \
         footprints) and the default careful point-cloud export against the ground-truth cloud (docs/geometry.md; \
         the cloud F-score at the threshold in the last column but one).\n"
    );
    let _ = writeln!(
        s,
        "| # | train s | step | depth \\|err\\| m | depth bias m | bias footprints | within 1 footprint | cloud median m | \
         cloud F | at m | standard |\n| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"
    );
    for r in results {
        for p in &r.points {
            let Some(g) = &p.geometry else { continue };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.index,
                secs(p.elapsed_s),
                p.step,
                o(g.depth_median_abs_m, 3),
                o(g.depth_bias_m, 3),
                o(g.depth_bias_footprints, 2),
                pct(g.depth_within_one_footprint),
                o(g.cloud_accuracy_median_m, 3),
                o(g.cloud_f_score, 3),
                o(g.cloud_threshold_m, 2),
                g.standard_pass.map_or(String::new(), |b| if b { "met".into() } else { "not met".into() })
            );
        }
    }
}
