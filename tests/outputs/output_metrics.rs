//! Metrics: analytic cases, scikit-image fixtures (tools/fixtures/gen_ssim_psnr.py), masks, and the ns-eval report.

use crate::output_support;
use msnerf::output::image::band;
use msnerf::output::metrics::{image_metrics, psnr, ssim, EvalReport, MetricOptions, ViewEval};
use msnerf::output::SpectralImage;
use output_support::{scratch, six_band, Rng};

#[derive(serde::Deserialize)]
struct Case {
    name: String,
    width: usize,
    height: usize,
    data_range: f64,
    gt: Vec<f64>,
    pred: Vec<f64>,
    ssim: f64,
    psnr: f64,
}

#[derive(serde::Deserialize)]
struct Fixture {
    cases: Vec<Case>,
}

#[test]
fn ssim_and_psnr_match_scikit_image() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/skimage_ssim_psnr.json"))
        .expect("fixture present");
    let fx: Fixture = serde_json::from_str(&text).expect("fixture parses");
    assert!(fx.cases.len() >= 6);
    for c in &fx.cases {
        let to32 = |v: &[f64]| -> Vec<f32> {
            v.iter()
                .map(|&x| {
                    // serde_json's default parser may be 1 ulp (f64) off; the nearest f32 is the stored one.
                    let f = x as f32;
                    assert!((f as f64 - x).abs() <= 1e-15 * x.abs().max(1.0), "{}: {x} is not an f32", c.name);
                    f
                })
                .collect()
        };
        let (gt, pred) = (to32(&c.gt), to32(&c.pred));
        let s = ssim::ssim(&pred, &gt, c.width, c.height, None, c.data_range).unwrap();
        let p = psnr(&pred, &gt, None, c.data_range).unwrap();
        assert!((s - c.ssim).abs() < 1e-9, "{}: ssim {s} vs skimage {}", c.name, c.ssim);
        assert!((p - c.psnr).abs() < 1e-9, "{}: psnr {p} vs skimage {}", c.name, c.psnr);
        // SSIM is symmetric.
        let s2 = ssim::ssim(&gt, &pred, c.width, c.height, None, c.data_range).unwrap();
        assert!((s - s2).abs() < 1e-12);
    }
}

#[test]
fn identical_images_give_infinite_psnr_and_unit_ssim() {
    let img = six_band(16, 13);
    let m = image_metrics(&img, &img, None, &MetricOptions::default()).unwrap();
    assert!(m.psnr.is_infinite() && m.psnr > 0.0);
    assert_eq!(m.ssim, 1.0);
    for b in &m.bands {
        assert!(b.psnr.is_infinite());
        assert_eq!(b.ssim, 1.0);
        assert_eq!(b.mse, 0.0);
    }
    // JSON has no infinity: the report writes null.
    let v = ViewEval { name: "v0".into(), metrics: m, num_rays: 16 * 13, render_seconds: None };
    let r = EvalReport::new("exp", "msnerf", "step-1", &img.bands, &[v], 1.0).unwrap();
    let j: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
    assert!(j["results"]["psnr"].is_null());
    assert_eq!(j["results"]["ssim"], 1.0);
}

#[test]
fn constant_offset_gives_exact_psnr() {
    // Values on a 1/256 grid plus an offset of 1/8: every difference is exactly 1/8 in f32.
    let mut rng = Rng(7);
    let gt: Vec<f32> = (0..20 * 15).map(|_| (rng.next_u64() % 128) as f32 / 256.0).collect();
    for c in [0.125f32, 0.0625, 0.25] {
        let pred: Vec<f32> = gt.iter().map(|v| v + c).collect();
        let p = psnr(&pred, &gt, None, 1.0).unwrap();
        let want = -10.0 * (c as f64 * c as f64).log10();
        assert!((p - want).abs() < 1e-12, "offset {c}: {p} vs {want}");
        // Data range is a parameter: R = 2 adds 20·log10(2).
        let p2 = psnr(&pred, &gt, None, 2.0).unwrap();
        assert!((p2 - want - 20.0 * 2f64.log10()).abs() < 1e-12);
    }
}

#[test]
fn blur_lowers_ssim_monotonically_and_flat_images_are_exact() {
    let (w, h) = (32, 24);
    let mut rng = Rng(11);
    let gt: Vec<f32> = (0..w * h).map(|_| rng.f64() as f32).collect();
    let blur = |img: &[f32], r: usize| -> Vec<f32> {
        // Box blur of radius r with clamped borders.
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut n) = (0.0, 0.0);
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        s += img[yy * w + xx];
                        n += 1.0;
                    }
                }
                out[y * w + x] = s / n;
            }
        }
        out
    };
    let s1 = ssim::ssim(&blur(&gt, 1), &gt, w, h, None, 1.0).unwrap();
    let s2 = ssim::ssim(&blur(&gt, 2), &gt, w, h, None, 1.0).unwrap();
    let s3 = ssim::ssim(&blur(&gt, 3), &gt, w, h, None, 1.0).unwrap();
    assert!(1.0 > s1 && s1 > s2 && s2 > s3 && s3 > 0.0, "{s1} {s2} {s3}");

    // Two flat images a and b: SSIM = (2ab + C1) / (a² + b² + C1) exactly (variances are 0).
    let (a, b) = (0.25f32, 0.5f32);
    let s = ssim::ssim(&vec![a; w * h], &vec![b; w * h], w, h, None, 1.0).unwrap();
    let c1 = 0.0001f64;
    let want = (2.0 * 0.25 * 0.5 + c1) / (0.0625 + 0.25 + c1);
    assert!((s - want).abs() < 1e-12, "{s} vs {want}");
}

#[test]
fn gaussian_window_is_eleven_taps_and_small_images_are_refused() {
    let k = ssim::gaussian_kernel();
    assert_eq!(k.len(), 11);
    assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    assert!((k[5] / k[4] - (0.5f64 / 2.25).exp()).abs() < 1e-12);
    let e = ssim::ssim(&[0.0; 100], &[0.0; 100], 10, 10, None, 1.0).unwrap_err().to_string();
    assert!(e.contains("smaller than the 11x11"), "{e}");
    let e = psnr(&[0.0; 3], &[0.0; 4], None, 1.0).unwrap_err().to_string();
    assert!(e.contains("mse"), "{e}");
    let e = psnr(&[0.0; 3], &[0.0; 3], None, 0.0).unwrap_err().to_string();
    assert!(e.contains("data_range"), "{e}");
}

#[test]
fn masks_restrict_psnr_and_ssim() {
    let (w, h) = (24, 20);
    let gt = six_band(w, h);
    let mut pred = gt.clone();
    // Corrupt the right half of every band.
    for b in 0..6 {
        for y in 0..h {
            for x in w / 2..w {
                pred.data[b * w * h + y * w + x] += 0.3;
            }
        }
    }
    // Keep the left half minus the SSIM window reach (6 px), so no kept window sees the corruption.
    let mask: Vec<bool> = (0..w * h).map(|i| i % w < w / 2 - 6).collect();
    let m = image_metrics(&pred, &gt, Some(&mask), &MetricOptions::default()).unwrap();
    assert!(m.psnr.is_infinite());
    assert!((m.ssim - 1.0).abs() < 1e-12, "{}", m.ssim);
    let full = image_metrics(&pred, &gt, None, &MetricOptions::default()).unwrap();
    assert!(full.psnr.is_finite() && full.ssim < 0.9);
    // Per band MSE over all pixels is half of 0.09.
    for b in &full.bands {
        assert!((b.mse - 0.045).abs() < 1e-6, "{}", b.mse);
    }
    let e = image_metrics(&pred, &gt, Some(&mask[1..]), &MetricOptions::default()).unwrap_err().to_string();
    assert!(e.contains("mask"), "{e}");
}

#[test]
fn eval_report_has_ns_eval_keys_per_band_and_per_view_entries() {
    let gt = six_band(16, 12);
    let mut views = Vec::new();
    for (i, off) in [0.01f32, 0.02, 0.04].iter().enumerate() {
        let pred =
            SpectralImage::from_planar(16, 12, gt.bands.clone(), gt.data.iter().map(|v| v + off).collect()).unwrap();
        let metrics = image_metrics(&pred, &gt, None, &MetricOptions::default()).unwrap();
        views.push(ViewEval {
            name: format!("frame_{i:03}"),
            metrics,
            num_rays: 16 * 12,
            render_seconds: Some(0.5 * (i + 1) as f64),
        });
    }
    let mut r =
        EvalReport::new("scene", "msnerf-nerfacto", "nerfstudio_models/step-000030000.ckpt", &gt.bands, &views, 1.0)
            .unwrap();
    let j: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
    for k in ["experiment_name", "method_name", "checkpoint", "results", "bands", "views", "data_range"] {
        assert!(j.get(k).is_some(), "missing {k}");
    }
    let res = &j["results"];
    for k in [
        "psnr",
        "psnr_std",
        "ssim",
        "ssim_std",
        "lpips",
        "lpips_std",
        "num_rays_per_sec",
        "num_rays_per_sec_std",
        "fps",
        "fps_std",
    ] {
        assert!(res.get(k).is_some(), "missing results.{k}");
    }
    assert!(res["lpips"].is_null());
    assert!(res["lpips_note"].as_str().unwrap().starts_with("not computed: "));
    let psnrs: Vec<f64> = views.iter().map(|v| v.metrics.psnr).collect();
    let mean = psnrs.iter().sum::<f64>() / 3.0;
    let std = (psnrs.iter().map(|p| (p - mean) * (p - mean)).sum::<f64>() / 2.0).sqrt();
    assert!((res["psnr"].as_f64().unwrap() - mean).abs() < 1e-9);
    assert!((res["psnr_std"].as_f64().unwrap() - std).abs() < 1e-9);
    // fps = 1/t averaged: (2 + 1 + 2/3) / 3.
    assert!((res["fps"].as_f64().unwrap() - (2.0 + 1.0 + 2.0 / 3.0) / 3.0).abs() < 1e-12);
    assert!((res["num_rays_per_sec"].as_f64().unwrap() - 192.0 * (2.0 + 1.0 + 2.0 / 3.0) / 3.0).abs() < 1e-9);
    assert_eq!(j["bands"].as_array().unwrap().len(), 6);
    assert_eq!(j["bands"][5]["center_nm"], 840.0);
    assert_eq!(j["views"].as_array().unwrap().len(), 3);
    assert_eq!(j["views"][1]["bands"].as_array().unwrap().len(), 6);
    assert_eq!(j["data_range"], 1.0);
    // A constant offset c gives PSNR −10·log10(c²) in every band.
    let b0 = j["views"][1]["bands"][0]["psnr"].as_f64().unwrap();
    assert!((b0 - -10.0 * (0.02f64).powi(2).log10()).abs() < 1e-3);
    assert!(r.table().contains("NIR 840nm"));

    // LPIPS hook.
    r.set_lpips(&[0.1, 0.2, 0.3]).unwrap();
    let j: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
    assert!((j["results"]["lpips"].as_f64().unwrap() - 0.2).abs() < 1e-12);
    assert!(j["results"].get("lpips_note").is_none());
    assert!(r.set_lpips(&[0.1]).is_err());

    let dir = scratch("eval_report");
    let path = dir.join("eval.json");
    r.write(&path).unwrap();
    let back: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(back["experiment_name"], "scene");
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no temporary file left behind");

    // Views without timings: null rates. Band-count mismatch: an error naming the view.
    let v = ViewEval { render_seconds: None, ..views[0].clone() };
    let r = EvalReport::new("s", "m", "c", &gt.bands, std::slice::from_ref(&v), 1.0).unwrap();
    assert!(r.results.fps.is_none());
    assert_eq!(r.results.psnr_std, 0.0);
    let e = EvalReport::new("s", "m", "c", &gt.bands[..5], &[v], 1.0).unwrap_err().to_string();
    assert!(e.contains("frame_000"), "{e}");
    let _ = band("x", None, None);
}

/// Depth metrics (`eval --depth`) against a direct f64 computation written from the definitions in the issue:
/// error = truth - prediction (positive = in front), footprint = truth / focal, pooled medians over views.
#[test]
fn depth_metrics_match_a_direct_computation() {
    use msnerf::output::metrics::depth::{DepthErrors, DepthReport};
    let mut rng = Rng(0x9e3779b97f4a7c15);
    let focal = 277.0;
    let mut views = Vec::new();
    let mut all_signed = Vec::new();
    let mut all_fp = Vec::new();
    for v in 0..3 {
        let n = 101 + 2 * v;
        let truth: Vec<f32> = (0..n).map(|_| 80.0 + 60.0 * rng.f64() as f32).collect();
        // A biased prediction: 0.3 m in front with noise of about one footprint, plus a masked-out pixel and an
        // invalid truth pixel that must not count.
        let mut pred: Vec<f32> = truth.iter().map(|&t| t - 0.3 + 0.4 * (rng.f64() as f32 - 0.5)).collect();
        let mut truth2 = truth.clone();
        truth2[0] = f32::NAN;
        pred[1] = f32::NAN; // a non-finite prediction counts with an infinite error
        let mask: Vec<bool> = (0..n).map(|i| i != 2).collect();
        let e = DepthErrors::of_view(&pred, &truth2, focal, Some(&mask)).expect("depth errors");
        for i in 0..n {
            if i == 0 || i == 2 {
                continue;
            }
            let p = if pred[i].is_finite() { pred[i] as f64 } else { f64::INFINITY };
            all_signed.push(truth2[i] as f64 - p);
            all_fp.push(truth2[i] as f64 / focal);
        }
        views.push((format!("view{v}"), e));
    }
    let r = DepthReport::new("median", &views);
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let m = v.len() / 2;
        if v.len() % 2 == 1 {
            v[m]
        } else {
            0.5 * (v[m - 1] + v[m])
        }
    };
    let n = all_signed.len();
    assert_eq!(r.overall.pixels, n);
    assert_eq!(r.overall.pixels, 3 * 101 + 2 + 4 - 6, "masked and invalid pixels excluded");
    let mut abs: Vec<f64> = all_signed.iter().map(|e| e.abs()).collect();
    let mut signed = all_signed.clone();
    let mut fp = all_fp.clone();
    let mut rel: Vec<f64> = all_signed.iter().zip(&all_fp).map(|(e, f)| e / f).collect();
    let within = |k: f64| all_signed.iter().zip(&all_fp).filter(|(e, f)| e.abs() <= k * **f).count() as f64 / n as f64;
    let o = r.overall;
    assert!((o.median_abs_error - med(&mut abs)).abs() < 1e-12);
    assert!((o.median_bias - med(&mut signed)).abs() < 1e-12);
    assert!((o.median_bias_footprints - med(&mut rel)).abs() < 1e-12);
    assert!((o.median_footprint - med(&mut fp)).abs() < 1e-12);
    assert!((o.within_half_footprint - within(0.5)).abs() < 1e-12);
    assert!((o.within_one_footprint - within(1.0)).abs() < 1e-12);
    assert!(o.mean_abs_error.is_infinite(), "the NaN prediction is an infinite error");
    assert!(o.median_bias > 0.2 && o.median_bias < 0.4, "in front by about 0.3 m: {}", o.median_bias);
    assert_eq!(r.views.len(), 3);
    let json = serde_json::to_string(&r).expect("json");
    assert!(json.contains("\"median_bias\"") && json.contains("\"view0\""), "{json}");
    // Shape errors name what is wrong.
    let err = DepthErrors::of_view(&[1.0, 2.0], &[1.0], focal, None).expect_err("length mismatch").to_string();
    assert!(err.contains("depth"), "{err}");
    assert!(DepthErrors::of_view(&[1.0], &[1.0], 0.0, None).is_err(), "zero focal length refused");
}
