//! The processing report of `msnerf process`: one HTML file with its pictures embedded (PNG as base64 data URLs), so
//! it opens in any browser with nothing fetched from the network, as Metashape's and ODM's reports give:
//!
//! - the stages: time and peak host/GPU memory;
//! - the camera and the import: captures, bands, irradiance source per band, panel, warnings;
//! - band registration: residual per band (median and largest over the captures);
//! - poses: registered frames, reprojection error, GPS against SfM positions (per frame, and drawn over the ortho);
//! - ground sampling distance and coverage;
//! - held-out PSNR and SSIM per band;
//! - the products: DSM hillshade, natural-colour ortho, NDVI, the point cloud's filters, and the confidence of the
//!   DSM's heights (photometrically supported, field only, nodata).
//!
//! Every section is built from the stage records (`stages/*.json`) and the files the stages wrote, so a report can
//! be rebuilt from a finished project. A number that is not finite is shown as `n/a`, never as NaN.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use base64::Engine as _;
use serde_json::Value;

use super::error::ProcessError;
use super::stage::{read_record, Stage};

/// Escapes text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "n/a".into(),
    }
}

fn mib(b: Option<u64>) -> String {
    b.map_or("n/a".into(), |b| format!("{:.0} MiB", b as f64 / 1048576.0))
}

fn table(head: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table><tr>");
    for h in head {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{}</td>", esc(c));
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

fn png_tag(bytes: &[u8], alt: &str) -> String {
    format!(
        "<img alt=\"{}\" src=\"data:image/png;base64,{}\">",
        esc(alt),
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// A section: `<section id=..><h2>title</h2>body</section>`.
fn section(id: &str, title: &str, body: &str) -> String {
    format!("<section id=\"{id}\"><h2>{}</h2>\n{body}\n</section>\n", esc(title))
}

/// Camera positions (GPS prior and SfM) drawn over the ortho preview.
fn positions_over_ortho(project: &Path, survey: &Value) -> Option<Vec<u8>> {
    let img = image::open(project.join("products/ortho_rgb.png")).ok()?.to_rgb8();
    let origin = survey["grid"]["origin"].as_array()?;
    let (ox, oy) = (origin.first()?.as_f64()?, origin.get(1)?.as_f64()?);
    let gsd = survey["gsd"].as_f64()?;
    let mut img = img;
    let (w, h) = (img.width() as i64, img.height() as i64);
    let mut dot = |x: f64, y: f64, c: [u8; 3], r: i64| {
        let (px, py) = (((x - ox) / gsd) as i64, ((oy - y) / gsd) as i64);
        for dy in -r..=r {
            for dx in -r..=r {
                let (qx, qy) = (px + dx, py + dy);
                if dx * dx + dy * dy <= r * r && qx >= 0 && qy >= 0 && qx < w && qy < h {
                    img.put_pixel(qx as u32, qy as u32, image::Rgb(c));
                }
            }
        }
    };
    for (p, c) in frame_positions(project) {
        if let Some(g) = p {
            dot(g[0], g[1], [255, 60, 40], 3);
        }
        if let Some(s) = c {
            dot(s[0], s[1], [40, 120, 255], 2);
        }
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).ok()?;
    Some(out.into_inner())
}

/// A frame's GPS prior position (from the import; None without a fix) and its SfM position (None: unregistered).
type FramePositions = (Option<[f64; 3]>, Option<[f64; 3]>);

/// Per frame, by file: [`FramePositions`].
fn frame_positions(project: &Path) -> Vec<FramePositions> {
    let pos = |f: &Value| -> Option<[f64; 3]> {
        let m = f["transform_matrix"].as_array()?;
        let c = |r: usize| m.get(r)?.as_array()?.get(3)?.as_f64();
        Some([c(0)?, c(1)?, c(2)?])
    };
    let (Some(prior), Some(posed)) = (
        read_json(&project.join("dataset/transforms.import.json")),
        read_json(&project.join("dataset/transforms.json")),
    ) else {
        return vec![];
    };
    let by_file = |v: &Value| -> Vec<(String, Option<[f64; 3]>, bool)> {
        v["frames"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|f| (f["file_path"].as_str().unwrap_or("").to_string(), pos(f), f["gps"].is_object()))
                    .collect()
            })
            .unwrap_or_default()
    };
    let posed = by_file(&posed);
    by_file(&prior)
        .into_iter()
        .map(|(file, p, has_gps)| {
            let s = posed.iter().find(|(f, _, _)| *f == file).and_then(|x| x.1);
            (p.filter(|_| has_gps), s)
        })
        .collect()
}

/// Writes `PROJECT/report.html` from the stage records and the products; returns its path.
pub fn write_report(project: &Path, flight: &Path) -> Result<PathBuf, ProcessError> {
    let rec = |s: Stage| read_record(project, s).ok().flatten();
    let mut body = String::new();

    // Stages.
    let rows: Vec<Vec<String>> = Stage::ALL
        .iter()
        .filter(|s| **s != Stage::Report)
        .map(|s| match rec(*s) {
            Some(r) => vec![
                s.name().into(),
                format!("{:.1} s", r.seconds),
                mib(r.peak_host_bytes),
                r.summary["planned_host_bytes"].as_u64().map_or("-".into(), |b| mib(Some(b))),
                mib(r.peak_gpu_bytes),
            ],
            None => vec![s.name().into(), "not run".into(), "n/a".into(), "-".into(), "n/a".into()],
        })
        .collect();
    body += &section(
        "stages",
        "Stages",
        &table(&["stage", "time", "peak host memory", "planned host memory", "peak GPU memory"], &rows),
    );

    // Import.
    let import = rec(Stage::Import).map(|r| r.summary).unwrap_or(Value::Null);
    let transforms = read_json(&project.join("dataset/transforms.json")).unwrap_or(Value::Null);
    let mut s = String::new();
    let _ = write!(
        s,
        "<p>Flight {}: {} captures, bands {}; units {}; irradiance from {}.</p>",
        esc(&flight.display().to_string()),
        import["captures"].as_u64().unwrap_or(0),
        esc(&import["bands"]
            .as_array()
            .map(|b| b.iter().filter_map(|x| x.as_str()).collect::<Vec<_>>().join(", "))
            .unwrap_or_default()),
        esc(import["units"].as_str().unwrap_or("n/a")),
        esc(import["calibration"].as_str().unwrap_or("n/a")),
    );
    let cal: Vec<Vec<String>> = transforms["calibration"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|c| {
                    vec![
                        c["band"].as_str().unwrap_or("").into(),
                        c["source"].as_str().unwrap_or("").into(),
                        c["light_sensor"].as_str().unwrap_or("-").into(),
                        num(c["irradiance"].as_f64(), 5),
                    ]
                })
                .collect()
        })
        .unwrap_or_default();
    s += &table(&["band", "irradiance from", "light-sensor tags", "panel irradiance W/(m² nm)"], &cal);
    let warnings: Vec<&str> =
        import["warnings"].as_array().map(|a| a.iter().filter_map(|w| w.as_str()).collect()).unwrap_or_default();
    if !warnings.is_empty() {
        s += "<ul class=\"warn\">";
        for w in warnings {
            let _ = write!(s, "<li>{}</li>", esc(w));
        }
        s += "</ul>";
    }
    body += &section("import", "Camera and radiometry", &s);

    // Registration.
    let ir = read_json(&project.join("dataset/import_report.json")).unwrap_or(Value::Null);
    let bands: Vec<String> = import["bands"]
        .as_array()
        .map(|b| b.iter().filter_map(|x| x.as_str().map(String::from)).collect())
        .unwrap_or_default();
    let mut per_band: Vec<Vec<f64>> = vec![Vec::new(); bands.len()];
    for set in ir["frames"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|f| &f["registration"])
        .chain(ir["rig_samples"].as_array().into_iter().flatten())
    {
        for (bi, r) in set.as_array().into_iter().flatten().enumerate() {
            if let (Some(v), Some(slot)) = (r["stats"]["residual_px"].as_f64(), per_band.get_mut(bi)) {
                slot.push(v);
            }
        }
    }
    let rows: Vec<Vec<String>> = bands
        .iter()
        .zip(&per_band)
        .map(|(b, v)| {
            if v.is_empty() {
                vec![b.clone(), "reference".into(), "-".into()]
            } else {
                vec![
                    b.clone(),
                    num(Some(crate::util::stats::median(v)), 3),
                    num(Some(v.iter().copied().fold(0.0, f64::max)), 3),
                ]
            }
        })
        .collect();
    let spread =
        import["rig_spread_px"].as_array().map(|a| a.iter().map(|v| num(v.as_f64(), 2)).collect::<Vec<_>>().join(", "));
    let mut s = table(&["band", "median residual (px)", "largest residual (px)"], &rows);
    let _ = write!(
        s,
        "<p>Registration: {}.{}</p>",
        esc(import["registration"].as_str().unwrap_or("n/a")),
        spread.map(|x| format!(" Shared warps' spread per band (px): {}", esc(&x))).unwrap_or_default()
    );
    body += &section("registration", "Band registration", &s);

    // Poses.
    let poses = rec(Stage::Poses).map(|r| r.summary).unwrap_or(Value::Null);
    let positions = frame_positions(project);
    let res: Vec<f64> = positions
        .iter()
        .filter_map(|(g, s)| {
            let (g, s) = ((*g)?, (*s)?);
            Some(((g[0] - s[0]).powi(2) + (g[1] - s[1]).powi(2) + (g[2] - s[2]).powi(2)).sqrt())
        })
        .collect();
    let mut s = format!(
        "<p>{} of {} frames registered; {} sparse points; mean reprojection error {} px; geo-registration: {}.</p>",
        poses["registered"].as_u64().unwrap_or(0),
        poses["frames"].as_u64().unwrap_or(0),
        poses["points"].as_u64().unwrap_or(0),
        num(poses["mean_reprojection_error_px"].as_f64(), 3),
        esc(&poses["georef"]
            .as_object()
            .map(|g| format!(
                "scale {}, RMS {} m, largest {} m, {} GPS fixes rejected",
                num(g.get("scale").and_then(Value::as_f64), 4),
                num(g.get("rms_m").and_then(Value::as_f64), 3),
                num(g.get("max_m").and_then(Value::as_f64), 3),
                g.get("rejected").and_then(Value::as_array).map_or(0, |r| r.len())
            ))
            .unwrap_or_else(|| "none".into())),
    );
    let _ = write!(
        s,
        "<p>GPS against SfM camera positions over {} frames: median {} m, largest {} m.</p>",
        res.len(),
        num((!res.is_empty()).then(|| crate::util::stats::median(&res)), 3),
        num(res.iter().copied().reduce(f64::max), 3)
    );
    if let Some(c) = poses["georef"]["control"].as_object() {
        let e = |v: &Value| {
            v.as_array().map_or("n/a".into(), |a| a.iter().map(|x| num(x.as_f64(), 3)).collect::<Vec<_>>().join(" / "))
        };
        let rows: Vec<Vec<String>> = c
            .get("points")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .map(|p| {
                vec![
                    esc(p["name"].as_str().unwrap_or("")),
                    p["views"].as_u64().unwrap_or(0).to_string(),
                    num(p["reprojection_px"].as_f64(), 2),
                    e(&p["residual_m"]),
                    e(&p["check_m"]),
                ]
            })
            .collect();
        let _ = write!(
            s,
            "<h3>Ground control</h3><p>{} point(s); residual RMS {} m; check RMS {} m (each point left out of the fit \
             in turn: the absolute accuracy to expect between the points).</p>",
            rows.len(),
            num(c.get("rms_m").and_then(Value::as_f64), 3),
            num(c.get("check_rms_m").and_then(Value::as_f64), 3)
        );
        s += &table(&["point", "views", "reprojection (px)", "residual E / N / U (m)", "check E / N / U (m)"], &rows);
        if let Some(a) = c.get("adjustment").and_then(Value::as_object) {
            let _ = write!(
                s,
                "<p>Bundle adjustment on the control points: {} iterations over {} observations, reprojection RMS {}                  -> {} px. The similarity fit alone: residual RMS {} m, check RMS {} m.</p>",
                a.get("iterations").and_then(Value::as_u64).unwrap_or(0),
                a.get("observations").and_then(Value::as_u64).unwrap_or(0),
                num(a.get("rms_px_before").and_then(Value::as_f64), 2),
                num(a.get("rms_px_after").and_then(Value::as_f64), 2),
                num(a.get("similarity_rms_m").and_then(Value::as_f64), 3),
                num(a.get("similarity_check_rms_m").and_then(Value::as_f64), 3)
            );
        }
        if let Some(g) = c.get("gps_shift_m").filter(|g| g.is_array()) {
            let _ = write!(
                s,
                "<p>The GPS's datum shift, found by the points from the fixes (E / N / U): {} m. GPS alone would have \
                 left it in every product.</p>",
                e(g)
            );
        }
        for n in c.get("notes").and_then(Value::as_array).into_iter().flatten() {
            let _ = write!(s, "<p>{}</p>", esc(n.as_str().unwrap_or("")));
        }
    }
    body += &section("poses", "Camera positions", &s);

    // Coverage and products.
    let survey = rec(Stage::Survey).map(|r| r.summary).unwrap_or(Value::Null);
    let st = &survey["stats"];
    let cells = st["cells"].as_f64();
    let valid = st["valid"].as_f64();
    let count = |k: &str| st[k].as_f64();
    let frac = |a: Option<f64>| num(a.zip(cells).map(|(a, c)| 100.0 * a / c.max(1.0)), 1) + " %";
    let gsd = survey["gsd"].as_f64();
    let area = cells.zip(gsd).map(|(c, g)| c * g * g);
    let mut s = format!(
        "<p>Ground sampling distance {} (world units); grid {} x {} cells, {} m² mapped.</p>",
        num(gsd, 3),
        survey["grid"]["width"].as_u64().unwrap_or(0),
        survey["grid"]["height"].as_u64().unwrap_or(0),
        num(area, 0)
    );
    s += &table(
        &["DSM cells", "share"],
        &[
            vec!["measured (photometric support)".into(), frac(count("measured"))],
            vec!["interpolated from measured cells".into(), frac(count("interpolated"))],
            vec!["field only (no photometric support)".into(), frac(count("field_only"))],
            vec!["nodata".into(), frac(cells.zip(valid).map(|(c, v)| c - v))],
        ],
    );
    if let Some(png) = positions_over_ortho(project, &survey) {
        s += "<figure>";
        s += &png_tag(&png, "camera positions over the ortho");
        s += "<figcaption>Camera positions over the true ortho: GPS (red), SfM (blue).</figcaption></figure>";
    }
    for (file, caption) in [
        ("products/dsm_hillshade.png", "DSM hillshade"),
        (
            "products/dsm_quality.png",
            "DSM quality: measured (green), interpolated (yellow), field only (orange), nodata (black)",
        ),
        ("products/ortho_rgb.png", "true ortho, natural colour"),
        ("products/ortho_ndvi.png", "NDVI"),
    ] {
        if let Ok(bytes) = std::fs::read(project.join(file)) {
            let _ = write!(s, "<figure>{}<figcaption>{}</figcaption></figure>", png_tag(&bytes, caption), esc(caption));
        }
    }
    body += &section("products", "Coverage and survey products", &s);

    // Terrain, canopy and trees.
    if let Some(t) = rec(Stage::Terrain).map(|r| r.summary) {
        let share = |a: Option<f64>, b: Option<f64>| num(a.zip(b).map(|(a, b)| 100.0 * a / b.max(1.0)), 1) + " %";
        let heights: Vec<f64> =
            t["trees"]["heights"].as_array().map(|a| a.iter().filter_map(Value::as_f64).collect()).unwrap_or_default();
        let mut s = table(
            &["DTM: ground cells", "CHM: cells at least 2 above the terrain", "trees", "tallest", "set apart (NDVI)"],
            &[vec![
                share(t["dtm"]["ground"].as_f64(), t["dtm"]["candidates"].as_f64()),
                share(t["chm"]["above_2m"].as_f64(), t["chm"]["cells"].as_f64()),
                t["trees"]["count"].as_u64().map_or("n/a".into(), |v| v.to_string()),
                num(heights.iter().copied().reduce(f64::max), 2),
                t["trees"]["not_vegetation"].as_u64().map_or("n/a".into(), |v| v.to_string()),
            ]],
        );
        s += "<p>The DTM is SMRF's ground (PDAL <code>filters.smrf</code> defaults) from the DSM's measured and \
              interpolated cells; trees are the CHM's local maxima in a window that grows with height, with crowns \
              grown from them; <code>products/trees.geojson</code> and <code>trees.csv</code> list each tree's \
              position, height, crown area, band means and NDVI.</p>";
        for (file, caption) in [
            ("products/dtm_hillshade.png", "DTM hillshade"),
            ("products/dtm_quality.png", "DTM: ground cells (green), interpolated beneath objects (yellow)"),
            ("products/chm_height.png", "canopy height model"),
        ] {
            if let Ok(bytes) = std::fs::read(project.join(file)) {
                let _ =
                    write!(s, "<figure>{}<figcaption>{}</figcaption></figure>", png_tag(&bytes, caption), esc(caption));
            }
        }
        body += &section("terrain", "Terrain, canopy and trees", &s);
    }

    // Held-out views.
    let eval = read_json(&project.join("run/eval.json")).unwrap_or(Value::Null);
    let rows: Vec<Vec<String>> = eval["bands"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|b| {
                    vec![
                        b["name"].as_str().unwrap_or("").into(),
                        num(b["psnr"].as_f64(), 2),
                        num(b["ssim"].as_f64(), 4),
                    ]
                })
                .collect()
        })
        .unwrap_or_default();
    let train = rec(Stage::Train).map(|r| r.summary).unwrap_or(Value::Null);
    let mut s = format!(
        "<p>{} held-out views (PSNR with data range 1). Training: {} steps of `{}` in {} s; depth supervision: {}.</p>",
        eval["num_views"].as_u64().unwrap_or(0),
        train["steps"].as_u64().unwrap_or(0),
        esc(train["model"].as_str().unwrap_or("n/a")),
        num(train["seconds"].as_f64(), 0),
        esc(train["depth_supervision"].as_str().unwrap_or("n/a")),
    );
    s += &table(&["band", "PSNR (dB)", "SSIM"], &rows);
    body += &section("accuracy", "Held-out views", &s);

    // Cloud.
    let cloud = rec(Stage::Cloud).map(|r| r.summary).unwrap_or(Value::Null);
    let s = table(
        &["points written", "rays", "inconsistent", "without photometric support"],
        &[vec![
            cloud["points"].as_u64().map_or("n/a".into(), |v| v.to_string()),
            cloud["rays"].as_u64().map_or("n/a".into(), |v| v.to_string()),
            cloud["inconsistent"].as_u64().map_or("n/a".into(), |v| v.to_string()),
            cloud["unsupported"].as_u64().map_or("n/a".into(), |v| v.to_string()),
        ]],
    );
    body += &section("cloud", "Point cloud", &s);

    let html = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>msnerf processing report</title>\n\
         <style>body{{font-family:sans-serif;max-width:70em;margin:auto;padding:1em}}table{{border-collapse:collapse;margin:.5em 0}}\
         td,th{{border:1px solid #bbb;padding:.2em .6em;text-align:left}}img{{max-width:100%}}figure{{display:inline-block;margin:.5em}}\
         .warn{{color:#a40}}</style></head>\n<body>\n<h1>msnerf processing report</h1>\n<p>Project {} (msnerf {}).</p>\n{body}</body></html>\n",
        esc(&project.display().to_string()),
        env!("CARGO_PKG_VERSION"),
    );
    let path = project.join("report.html");
    crate::util::atomic::write_bytes(&path, html.as_bytes())
        .map_err(|e| ProcessError::Output { path: path.clone(), reason: e.to_string() })?;
    Ok(path)
}
