//! The sweep's plots, each drawn once per backend into memory and written atomically as SVG and PNG:
//! - `psnr_vs_time`: held-out PSNR against training time, one line per configuration, the Pareto front marked;
//! - `kernel_times`: milliseconds per training step, stacked by kernel, one bar per configuration;
//! - `memory_vs_psnr`: final held-out PSNR against peak GPU memory, the Pareto front marked.
//!
//! Text is rasterised by ab_glyph from a font compiled into the binary (no system font libraries needed).

use super::error::SweepError;
use super::pareto::{memory_front, memory_points, time_front, time_points};
use super::result::CellResult;
use crate::util::atomic;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

const SIZE: (u32, u32) = (960, 600);
const FONT: &str = "sans-serif";

fn register_fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        for family in ["sans-serif", "serif", "monospace"] {
            // The bytes are a valid TrueType font compiled in; a failure here would only lose text.
            let _ = plotters::style::register_font(family, FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT);
        }
    });
}

fn err<E: std::fmt::Debug>(e: E) -> SweepError {
    SweepError::Plot(format!("{e:?}"))
}

fn colour(i: usize) -> RGBColor {
    let c = Palette99::pick(i).to_rgba();
    RGBColor(c.0, c.1, c.2)
}

fn short(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        s.chars().take(n - 1).collect::<String>() + "…"
    }
}

fn legend_label(r: &CellResult) -> String {
    format!("#{} {}", r.index, short(&r.label, 48))
}

/// Lowers the bottom of a y range so that the legend (lower right, one line per configuration plus the front)
/// sits below the data instead of over it.
fn legend_room((lo, hi): (f64, f64), entries: usize) -> (f64, f64) {
    // About 22 px per legend line out of ~500 px of plot height.
    let share = ((entries + 1) as f64 * 22.0 / 500.0).min(0.6);
    (lo - (hi - lo) * share / (1.0 - share), hi)
}

/// (min, max) with a margin; a fallback range when there is nothing finite.
fn span(values: impl Iterator<Item = f64>, pad: f64, fallback: (f64, f64)) -> (f64, f64) {
    let v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return fallback;
    }
    let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let p = ((hi - lo) * pad).max(pad.max(1e-3));
    (lo - p, hi + p)
}

fn draw_psnr_vs_time<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    results: &[CellResult],
) -> Result<(), SweepError> {
    root.fill(&WHITE).map_err(err)?;
    let pts = time_points(results);
    let (_, x1) = span(pts.iter().map(|p| p.2), 0.05, (0.0, 1.0));
    let (y0, y1) = legend_room(span(pts.iter().map(|p| p.3), 0.08, (0.0, 40.0)), results.len());
    let mut chart = ChartBuilder::on(root)
        .caption("Held-out PSNR against training time", (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..x1.max(1.0), y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .max_light_lines(1)
        .x_desc("training time (s, wall clock; evaluation not counted)")
        .y_desc("held-out PSNR (dB, all bands)")
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .draw()
        .map_err(err)?;
    for (i, r) in results.iter().enumerate() {
        let c = colour(i);
        let line: Vec<(f64, f64)> =
            r.points.iter().filter(|p| p.psnr.is_finite()).map(|p| (p.target_s, p.psnr)).collect();
        chart
            .draw_series(LineSeries::new(line.clone(), c.stroke_width(2)))
            .map_err(err)?
            .label(legend_label(r))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        chart.draw_series(line.iter().map(|&p| Circle::new(p, 4, c.filled()))).map_err(err)?;
    }
    let front: Vec<(f64, f64)> = time_front(results)
        .into_iter()
        .map(|(c, p)| (results[c].points[p].target_s, results[c].points[p].psnr))
        .collect();
    finish_with_front(root, &mut chart, front, 9)
}

/// Draws the Pareto front (a line through rings of `radius` px), the legend, and presents the drawing.
fn finish_with_front<'a, DB: DrawingBackend + 'a>(
    root: &DrawingArea<DB, Shift>,
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    front: Vec<(f64, f64)>,
    radius: i32,
) -> Result<(), SweepError> {
    if !front.is_empty() {
        chart
            .draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(1)))
            .map_err(err)?
            .label("Pareto front (models of every band)")
            .legend(|(x, y)| Circle::new((x + 9, y), 7, BLACK.stroke_width(2)));
        chart.draw_series(front.iter().map(|&p| Circle::new(p, radius, BLACK.stroke_width(2)))).map_err(err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// The kernels drawn by name (the most expensive over all cells), the rest summed as "other".
fn top_kernels(results: &[CellResult], n: usize) -> Vec<String> {
    let mut total: Vec<(String, f64)> = Vec::new();
    for r in results {
        for k in &r.kernels {
            match total.iter_mut().find(|t| t.0 == k.name) {
                Some(t) => t.1 += k.ms_per_step,
                None => total.push((k.name.clone(), k.ms_per_step)),
            }
        }
    }
    total.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    total.into_iter().take(n).map(|t| t.0).collect()
}

fn draw_kernel_times<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    results: &[CellResult],
) -> Result<(), SweepError> {
    root.fill(&WHITE).map_err(err)?;
    let names = top_kernels(results, 8);
    let n = results.len().max(1);
    let ymax = results
        .iter()
        .map(|r| r.gpu_ms_per_step.max(r.kernels.iter().map(|k| k.ms_per_step).sum()))
        .fold(0.0, f64::max);
    let mut chart = ChartBuilder::on(root)
        .caption("GPU time per training step, by kernel", (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.6..(n as f64 - 0.4), 0.0..(ymax * 1.45).max(1e-3))
        .map_err(err)?;
    chart
        .configure_mesh()
        .max_light_lines(1)
        .disable_x_mesh()
        .x_labels(n.min(30))
        .x_label_formatter(&|x| {
            if (x - x.round()).abs() < 1e-6 && *x >= 0.0 {
                format!("#{}", x.round() as usize)
            } else {
                String::new()
            }
        })
        .x_desc("configuration (# as in the report)")
        .y_desc("ms per step")
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .draw()
        .map_err(err)?;
    let mut layers: Vec<(String, Vec<f64>)> = names
        .iter()
        .map(|k| {
            (
                k.clone(),
                results
                    .iter()
                    .map(|r| r.kernels.iter().filter(|x| &x.name == k).map(|x| x.ms_per_step).sum())
                    .collect(),
            )
        })
        .collect();
    layers.push((
        "other".into(),
        results
            .iter()
            .map(|r| r.kernels.iter().filter(|x| !names.contains(&x.name)).map(|x| x.ms_per_step).sum())
            .collect(),
    ));
    let mut base = vec![0.0f64; results.len()];
    for (li, (name, vals)) in layers.iter().enumerate() {
        let c = colour(li + 3);
        let rects: Vec<Rectangle<(f64, f64)>> = vals
            .iter()
            .enumerate()
            .map(|(i, v)| {
                Rectangle::new(
                    [(results[i].index as f64 - 0.35, base[i]), (results[i].index as f64 + 0.35, base[i] + v)],
                    c.filled(),
                )
            })
            .collect();
        for (b, v) in base.iter_mut().zip(vals) {
            *b += v;
        }
        chart
            .draw_series(rects)
            .map_err(err)?
            .label(name.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

fn draw_memory_vs_psnr<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    results: &[CellResult],
) -> Result<(), SweepError> {
    root.fill(&WHITE).map_err(err)?;
    let pts = memory_points(results);
    let (x0, x1) = span(pts.iter().map(|p| p.0), 0.1, (0.0, 1.0));
    let (y0, y1) = legend_room(span(pts.iter().map(|p| p.1), 0.1, (0.0, 40.0)), results.len());
    let mut chart = ChartBuilder::on(root)
        .caption("Final held-out PSNR against peak GPU memory", (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(x0.max(0.0)..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .max_light_lines(1)
        .x_desc("peak GPU memory (MiB)")
        .y_desc("held-out PSNR at the end of the budget (dB)")
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .draw()
        .map_err(err)?;
    for (i, (r, p)) in results.iter().zip(&pts).enumerate() {
        if !(p.0.is_finite() && p.1.is_finite()) {
            continue;
        }
        let c = colour(i);
        chart
            .draw_series(std::iter::once(Circle::new(*p, 6, c.filled())))
            .map_err(err)?
            .label(legend_label(r))
            .legend(move |(x, y)| Circle::new((x + 9, y), 5, c.filled()));
        chart
            .draw_series(std::iter::once(
                EmptyElement::at(*p) + Text::new(format!("#{}", r.index), (10, -18), (FONT, 15).into_font()),
            ))
            .map_err(err)?;
    }
    let front: Vec<(f64, f64)> = memory_front(results).into_iter().map(|i| pts[i]).collect();
    finish_with_front(root, &mut chart, front, 10)
}

/// Draws with both backends and writes `dir/stem.svg` and `dir/stem.png` atomically.
macro_rules! both {
    ($dir:expr, $stem:expr, $draw:ident, $results:expr, $out:expr) => {{
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
            $draw(&root, $results)?;
        }
        let mut rgb = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area();
            $draw(&root, $results)?;
        }
        let svg_path = $dir.join(format!("{}.svg", $stem));
        atomic::write_bytes(&svg_path, svg.as_bytes())?;
        let png_path = $dir.join(format!("{}.png", $stem));
        write_png(&png_path, rgb)?;
        $out.push(svg_path);
        $out.push(png_path);
    }};
}

fn write_png(path: &Path, rgb: Vec<u8>) -> Result<(), SweepError> {
    let img = image::RgbImage::from_raw(SIZE.0, SIZE.1, rgb)
        .ok_or_else(|| SweepError::Plot("plot buffer has the wrong size".into()))?;
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| SweepError::file(path, e))?;
    Ok(atomic::write_bytes(path, &bytes)?)
}

/// Writes every plot into `dir` (created if needed); returns the files written.
pub fn write_plots(results: &[CellResult], dir: &Path) -> Result<Vec<PathBuf>, SweepError> {
    register_fonts();
    std::fs::create_dir_all(dir).map_err(|e| SweepError::file(dir, e))?;
    let mut out = Vec::new();
    both!(dir, "psnr_vs_time", draw_psnr_vs_time, results, out);
    both!(dir, "kernel_times", draw_kernel_times, results, out);
    both!(dir, "memory_vs_psnr", draw_memory_vs_psnr, results, out);
    Ok(out)
}
