#![allow(clippy::needless_range_loop)] // the reference loops read as the definition they implement
//! LPIPS (`msnerf::output::metrics::lpips`) with random AlexNet-shaped weights (msnerf ships no pretrained network, and
//! none can be fetched here): the fast path (im2col + sgemm, f32) against an independent direct-convolution f64
//! implementation written below from the LPIPS definition (tolerance 1e-4 relative); identity, symmetry and growth
//! with the difference; every malformed weights file named with its tensor; `msnerf eval --lpips-weights` puts
//! per-view numbers and the composite's bands in eval.json, and without weights LPIPS stays null.

use crate::common;
use msnerf::output::metrics::lpips::Lpips;
use rand::Rng;
use std::collections::HashMap;
use std::path::Path;

const CONVS: [(&str, usize, usize, usize, usize, usize); 5] = [
    ("net.slice1.0", 64, 3, 11, 4, 2),
    ("net.slice2.3", 192, 64, 5, 1, 2),
    ("net.slice3.6", 384, 192, 3, 1, 1),
    ("net.slice4.8", 256, 384, 3, 1, 1),
    ("net.slice5.10", 256, 256, 3, 1, 1),
];

type Tensors = HashMap<String, (Vec<usize>, Vec<f32>)>;

/// AlexNet-shaped weights with He-like scales (features neither vanish nor explode) and non-negative lin weights.
fn random_weights(seed: u64) -> Tensors {
    let mut r = common::rng(seed);
    let mut t = Tensors::new();
    for (i, &(name, out, inp, k, _, _)) in CONVS.iter().enumerate() {
        let a = (6.0 / (inp * k * k) as f32).sqrt();
        t.insert(
            format!("{name}.weight"),
            (vec![out, inp, k, k], (0..out * inp * k * k).map(|_| r.random_range(-a..a)).collect()),
        );
        t.insert(format!("{name}.bias"), (vec![out], (0..out).map(|_| r.random_range(-0.1..0.1)).collect()));
        t.insert(
            format!("lin{i}.model.1.weight"),
            (vec![1, out, 1, 1], (0..out).map(|_| r.random_range(0.0..0.2)).collect()),
        );
    }
    t
}

fn write_safetensors(t: &Tensors, path: &Path) {
    let bytes: Vec<(String, Vec<u8>, Vec<usize>)> =
        t.iter().map(|(k, (s, v))| (k.clone(), v.iter().flat_map(|x| x.to_le_bytes()).collect(), s.clone())).collect();
    let views: Vec<(String, safetensors::tensor::TensorView)> = bytes
        .iter()
        .map(|(k, b, s)| {
            (k.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).expect("view"))
        })
        .collect();
    std::fs::write(path, safetensors::serialize(views, None).expect("serialize")).expect("write");
}

fn from_map(t: &Tensors) -> Result<Lpips, String> {
    Lpips::from_tensors(|n| t.get(n).cloned().ok_or_else(|| "missing".to_string()))
}

/// The LPIPS definition, directly: f64, direct convolution loops, no im2col.
fn reference_lpips(t: &Tensors, a: &[f32], b: &[f32], w: usize, h: usize) -> f64 {
    let shift = [-0.030, -0.088, -0.188];
    let scale = [0.458, 0.448, 0.450];
    let feats = |img: &[f32]| -> Vec<(usize, usize, usize, Vec<f64>)> {
        let mut cur: (usize, usize, usize, Vec<f64>) = (
            3,
            h,
            w,
            img.iter()
                .enumerate()
                .map(|(i, &v)| (2.0 * v as f64 - 1.0 - shift[i / (w * h)]) / scale[i / (w * h)])
                .collect(),
        );
        let mut taps = Vec::new();
        for (li, &(name, out, inp, k, s, p)) in CONVS.iter().enumerate() {
            if li == 1 || li == 2 {
                let (c, hh, ww, d) = &cur;
                let (oh, ow) = ((hh - 3) / 2 + 1, (ww - 3) / 2 + 1);
                let mut o = vec![f64::MIN; c * oh * ow];
                for ci in 0..*c {
                    for y in 0..oh {
                        for x in 0..ow {
                            for dy in 0..3 {
                                for dx in 0..3 {
                                    let v = d[(ci * hh + 2 * y + dy) * ww + 2 * x + dx];
                                    o[(ci * oh + y) * ow + x] = o[(ci * oh + y) * ow + x].max(v);
                                }
                            }
                        }
                    }
                }
                cur = (*c, oh, ow, o);
            }
            let (wt, bias) = (&t[&format!("{name}.weight")].1, &t[&format!("{name}.bias")].1);
            let (_, hh, ww, d) = &cur;
            let (oh, ow) = ((hh + 2 * p - k) / s + 1, (ww + 2 * p - k) / s + 1);
            let mut o = vec![0.0; out * oh * ow];
            for co in 0..out {
                for y in 0..oh {
                    for x in 0..ow {
                        let mut acc = bias[co] as f64;
                        for ci in 0..inp {
                            for ky in 0..k {
                                for kx in 0..k {
                                    let (iy, ix) =
                                        ((y * s + ky) as isize - p as isize, (x * s + kx) as isize - p as isize);
                                    if iy >= 0 && ix >= 0 && (iy as usize) < *hh && (ix as usize) < *ww {
                                        acc += wt[((co * inp + ci) * k + ky) * k + kx] as f64
                                            * d[(ci * hh + iy as usize) * ww + ix as usize];
                                    }
                                }
                            }
                        }
                        o[(co * oh + y) * ow + x] = acc.max(0.0);
                    }
                }
            }
            cur = (out, oh, ow, o);
            taps.push(cur.clone());
        }
        taps
    };
    let (fa, fb) = (feats(a), feats(b));
    let mut total = 0.0;
    for (i, (ta, tb)) in fa.iter().zip(&fb).enumerate() {
        let lin = &t[&format!("lin{i}.model.1.weight")].1;
        let (c, hh, ww) = (ta.0, ta.1, ta.2);
        let px = hh * ww;
        let mut sum = 0.0;
        for p in 0..px {
            let na = (0..c).map(|k| ta.3[k * px + p].powi(2)).sum::<f64>().sqrt() + 1e-10;
            let nb = (0..c).map(|k| tb.3[k * px + p].powi(2)).sum::<f64>().sqrt() + 1e-10;
            for k in 0..c {
                let d = ta.3[k * px + p] / na - tb.3[k * px + p] / nb;
                sum += lin[k] as f64 * d * d;
            }
        }
        total += sum / px as f64;
    }
    total
}

fn image(seed: u64, w: usize, h: usize) -> Vec<f32> {
    let mut r = common::rng(seed);
    // Smooth structure plus noise, in [0, 1].
    (0..3 * w * h)
        .map(|i| {
            let (c, y, x) = (i / (w * h), (i / w) % h, i % w);
            (0.5 + 0.3 * ((x as f32 * 0.3 + c as f32).sin() * (y as f32 * 0.2).cos()) + r.random_range(-0.1..0.1))
                .clamp(0.0, 1.0)
        })
        .collect()
}

#[test]
fn matches_a_direct_f64_implementation_of_the_definition() {
    let t = random_weights(1);
    let net = from_map(&t).expect("weights");
    for (w, h, seed) in [(47, 39, 2), (64, 48, 3)] {
        let (a, b) = (image(seed, w, h), image(seed + 10, w, h));
        let got = net.distance(&a, &b, w, h).expect("lpips");
        let want = reference_lpips(&t, &a, &b, w, h);
        assert!((got - want).abs() <= 1e-4 * want.abs(), "{w}x{h}: {got} vs {want}");
        assert!(got > 0.0);
    }
}

#[test]
fn identity_symmetry_and_growth_with_the_difference() {
    let net = from_map(&random_weights(4)).expect("weights");
    let (w, h) = (64, 48);
    let a = image(5, w, h);
    assert_eq!(net.distance(&a, &a, w, h).expect("lpips"), 0.0);
    let mut r = common::rng(6);
    let noise: Vec<f32> = (0..a.len()).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let with = |amp: f32| -> Vec<f32> { a.iter().zip(&noise).map(|(x, n)| (x + amp * n).clamp(0.0, 1.0)).collect() };
    let (small, large) = (with(0.02), with(0.2));
    let d_small = net.distance(&a, &small, w, h).expect("lpips");
    assert_eq!(d_small, net.distance(&small, &a, w, h).expect("lpips"), "symmetric");
    assert!(net.distance(&a, &large, w, h).expect("lpips") > d_small, "more noise, larger distance");
}

#[test]
fn malformed_weights_are_errors_that_name_the_tensor() {
    let dir = common::TempDir::new("lpips");
    let good = random_weights(7);
    let mut missing = good.clone();
    missing.remove("lin3.model.1.weight");
    let e = from_map(&missing).err().expect("missing tensor");
    assert!(e.contains("lin3.model.1.weight") && e.contains("missing"), "{e}");
    let mut shape = good.clone();
    shape.get_mut("net.slice2.3.bias").expect("bias").0 = vec![191];
    let e = from_map(&shape).err().expect("wrong shape");
    assert!(e.contains("net.slice2.3.bias") && e.contains("[191]"), "{e}");
    let mut nan = good.clone();
    nan.get_mut("net.slice5.10.weight").expect("w").1[3] = f32::NAN;
    assert!(from_map(&nan).err().expect("NaN").contains("net.slice5.10.weight"));
    // Files: not safetensors, absent, and a round trip through a real file.
    let junk = dir.path().join("junk.safetensors");
    std::fs::write(&junk, b"not a weights file").expect("write");
    let e = Lpips::load(&junk).err().expect("junk");
    assert!(e.contains("junk.safetensors") && e.contains("not a safetensors file"), "{e}");
    assert!(Lpips::load(&dir.path().join("absent.safetensors")).err().expect("absent").contains("absent.safetensors"));
    let file = dir.path().join("w.safetensors");
    write_safetensors(&missing, &file);
    let e = Lpips::load(&file).err().expect("missing in file");
    assert!(e.contains("w.safetensors") && e.contains("lin3.model.1.weight"), "{e}");
    write_safetensors(&good, &file);
    let (w, h) = (40, 40);
    let (a, b) = (image(8, w, h), image(9, w, h));
    let from_file = Lpips::load(&file).expect("loads").distance(&a, &b, w, h).expect("lpips");
    assert_eq!(from_file, from_map(&good).expect("map").distance(&a, &b, w, h).expect("lpips"));
    // Images AlexNet cannot take.
    let e = from_map(&good).expect("map").distance(&image(1, 20, 20), &image(2, 20, 20), 20, 20).expect_err("small");
    assert!(e.contains("20 x 20"), "{e}");
}

#[test]
fn eval_reports_lpips_per_view_with_a_weights_file_and_null_without() {
    use msnerf::nerf::config::ModelConfig;
    use msnerf::nerf::trainer::train;
    let dir = common::TempDir::new("lpips-eval");
    let data = dir.path().join("data");
    common::simulate_ci_small(&data);
    let mut model = ModelConfig::resolve("tiny").expect("tiny");
    model.trainer.max_steps = 10;
    let run = dir.path().join("run");
    train(&common::gpu(), &common::train_options(&data, &run, model, 256)).expect("train");
    let weights = dir.path().join("lpips.safetensors");
    write_safetensors(&random_weights(11), &weights);
    let eval = |extra: &[&str]| -> serde_json::Value {
        let out = dir.path().join("eval.json");
        let mut args = vec!["eval", run.to_str().expect("utf-8"), "--output", out.to_str().expect("utf-8")];
        args.extend_from_slice(extra);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf")).args(&args).output().expect("msnerf");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_str(&std::fs::read_to_string(&out).expect("eval.json")).expect("json")
    };
    let without = eval(&[]);
    assert!(without["results"]["lpips"].is_null(), "{}", without["results"]);
    let with = eval(&["--lpips-weights", weights.to_str().expect("utf-8")]);
    let r = &with["results"];
    assert!(r["lpips"].as_f64().is_some_and(|v| v > 0.0 && v.is_finite()), "{r}");
    let note = r["lpips_note"].as_str().expect("note");
    assert!(note.contains("Red") || note.contains("red"), "the composite's bands are named: {note}");
    let views = with["views"].as_array().expect("views");
    assert!(!views.is_empty() && views.iter().all(|v| v["lpips"].is_number()), "{views:?}");
    // A broken weights file fails before anything is rendered, naming the file.
    let bad = dir.path().join("bad.safetensors");
    std::fs::write(&bad, b"x").expect("write");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_msnerf"))
        .args(["eval", run.to_str().expect("utf-8"), "--lpips-weights", bad.to_str().expect("utf-8")])
        .output()
        .expect("msnerf");
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("bad.safetensors"));
}
