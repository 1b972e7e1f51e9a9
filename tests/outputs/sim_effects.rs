//! Each effect: `enabled: false` writes exactly the bytes of a scene without it, and turned on it has its
//! measured effect (vignetting radial fall-off, misregistration pixel shift, exposure drift gain, noise std
//! and 12-bit quantisation).

use crate::sim_support;
use msnerf::sim::SimOptions;
use sim_support::*;

const W: u32 = 40;
const H: u32 = 30;

fn effect_scene(effects: &str) -> String {
    // Textured ground (regions and a box) so that shifts are visible.
    let extra = format!(
        "regions:\n  - {{material: dark, rect: {{center: [2, 1], size: [6, 3], yaw_deg: 25}}}}\n  - {{material: roof, circle: {{center: [-5, -4], radius: 2.5}}}}\n\
boxes:\n  - {{center: [6, -5], size: [3, 4, 5], material: wall, roof: roof}}\n{effects}"
    );
    panel_scene(W, H, &extra)
}

#[test]
fn disabled_effects_are_bit_identical_to_absent_ones() {
    let t = TempDir::new("off");
    let write = |yaml: &str, name: &str| {
        let out = t.path().join(name);
        msnerf::sim::simulate(&scene(yaml), &SimOptions::default(), &out).unwrap();
        files(&out)
    };
    let base = write(&effect_scene(""), "base");
    let effects = [
        "sun: {enabled: false, azimuth_deg: 90, elevation_deg: 40}",
        "vegetation_brdf: {enabled: false}",
        "misregistration: {enabled: false, bands: [{band: nir, shift_px: [2, 1]}]}",
        "vignetting: {enabled: false, coeffs: [-0.3]}",
        "exposure_drift: {enabled: false, std: 0.05}",
        "noise: {enabled: false, std: 0.01}",
    ];
    for (i, e) in effects.iter().enumerate() {
        let got = write(&effect_scene(&format!("effects:\n  {e}\n")), &format!("e{i}"));
        assert_eq!(got.len(), base.len());
        for (a, b) in got.iter().zip(&base) {
            assert!(a == b, "{e}: {} differs", a.0);
        }
    }
    // Zero-strength effects change no pixel either (vignetting 0, zero shift, unit gains).
    for e in [
        "vignetting: {coeffs: [0, 0, 0]}",
        "misregistration: {bands: [{band: red, shift_px: [0, 0]}]}",
        "exposure_drift: {gains: [1.0]}",
    ] {
        let got = write(&effect_scene(&format!("effects:\n  {e}\n")), "zero");
        for (a, b) in got.iter().zip(&base) {
            if a.0.starts_with("images/") || a.0.starts_with("depth/") || a.0 == "transforms.json" {
                assert!(a == b, "{e}: {} differs", a.0);
            }
        }
        std::fs::remove_dir_all(t.path().join("zero")).unwrap();
    }
}

#[test]
fn vignetting_falls_off_radially() {
    let k = [-0.3, 0.05, -0.02];
    let (_a, ds) =
        run_yaml(&effect_scene(&format!("effects:\n  vignetting: {{coeffs: [{}, {}, {}]}}\n", k[0], k[1], k[2])));
    let (_b, plain) = run_yaml(&effect_scene(""));
    let half_diag = 0.5 * ((W * W + H * H) as f64).sqrt();
    let mut corner = 1.0;
    for i in 0..ds.frames.len() {
        let (img, ref_img) = (frame(&ds, i), frame(&plain, i));
        for row in 0..H {
            for col in 0..W {
                let r2 = ((col as f64 + 0.5 - W as f64 / 2.0).powi(2) + (row as f64 + 0.5 - H as f64 / 2.0).powi(2))
                    / (half_diag * half_diag);
                let v = 1.0 + k[0] * r2 + k[1] * r2 * r2 + k[2] * r2 * r2 * r2;
                for b in 0..6 {
                    let expect = ref_img.get(row, col, b) as f64 * v;
                    assert!((img.get(row, col, b) as f64 - expect).abs() < 1e-6, "({row},{col})");
                }
                if (row, col) == (0, 0) {
                    corner = v;
                }
            }
        }
    }
    // The corner loses about a quarter; the centre pixels almost nothing.
    assert!(corner < 0.8 && corner > 0.7, "{corner}");
    let img = frame(&ds, 0);
    let ref_img = frame(&plain, 0);
    assert!((img.get(14, 19, 0) / ref_img.get(14, 19, 0) - 1.0).abs() < 1e-3);
}

#[test]
fn misregistration_shifts_a_band_by_the_configured_pixels() {
    let (_a, ds) = run_yaml(&effect_scene(
        "effects:\n  misregistration:\n    bands: [{band: nir, shift_px: [3, -2]}, {band: blue, rotation_deg: 180}]\n",
    ));
    let (_b, plain) = run_yaml(&effect_scene(""));
    let (mut shifted_diff, mut rot_close, mut rot_total) = (0, 0, 0);
    for i in 0..ds.frames.len() {
        let (img, r) = (frame(&ds, i), frame(&plain, i));
        for row in 0..H {
            for col in 0..W {
                // Bands without misregistration are untouched.
                for b in 1..5 {
                    assert_eq!(img.get(row, col, b), r.get(row, col, b));
                }
                // NIR: content moved 3 px right and 2 px up: out(col, row) = ref(col - 3, row + 2), exactly.
                let (sc, sr) = (col as i64 - 3, row as i64 + 2);
                if sc >= 0 && sr < H as i64 {
                    assert_eq!(img.get(row, col, 5), r.get(sr as u32, sc as u32, 5), "nir ({row},{col})");
                    shifted_diff += usize::from(img.get(row, col, 5) != r.get(row, col, 5));
                }
                // Blue rotated by 180 degrees about the image centre.
                rot_total += 1;
                let v = r.get(H - 1 - row, W - 1 - col, 0);
                rot_close += usize::from((img.get(row, col, 0) - v).abs() < 1e-6);
            }
        }
        // Depth belongs to the reference ray.
        assert_eq!(ds.read_depth(i).unwrap(), plain.read_depth(i).unwrap());
    }
    assert!(shifted_diff > 50, "the shift is visible: {shifted_diff}");
    assert!(rot_close as f64 > 0.99 * rot_total as f64, "{rot_close}/{rot_total}");
}

#[test]
fn exposure_drift_changes_per_view_gain() {
    let (_a, ds) = run_yaml(&effect_scene("effects:\n  exposure_drift: {gains: [1.0, 1.25, 0.8]}\n"));
    let (_b, plain) = run_yaml(&effect_scene(""));
    for (i, g) in [1.0, 1.25, 0.8].iter().enumerate() {
        let (img, r) = (frame(&ds, i), frame(&plain, i));
        for row in 0..H {
            for col in 0..W {
                for b in 0..6 {
                    assert!((img.get(row, col, b) as f64 - r.get(row, col, b) as f64 * g).abs() < 1e-7);
                }
            }
        }
    }
    // Random drift: the gains in simulation.json are applied, differ between views, per band with band_std.
    let (_c, ds) = run_yaml(&effect_scene("effects:\n  exposure_drift: {std: 0.05, band_std: 0.01}\n"));
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ds.root.join("simulation.json")).unwrap()).unwrap();
    let gains = meta["exposure_gains"].as_array().unwrap();
    assert_eq!(gains.len(), 3);
    let mut distinct = Vec::new();
    for (i, gv) in gains.iter().enumerate() {
        let (img, r) = (frame(&ds, i), frame(&plain, i));
        for b in 0..6 {
            let g = gv[b].as_f64().unwrap();
            assert!((g - 1.0).abs() < 0.3);
            distinct.push(g);
            assert!((img.get(7, 9, b) as f64 - r.get(7, 9, b) as f64 * g).abs() < 1e-7);
        }
    }
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    assert_eq!(distinct.len(), 18);
}

#[test]
fn noise_has_the_configured_std_and_is_12_bit() {
    // Flat 0.4 panel everywhere: no texture, so the pixel spread is the noise.
    let yaml = panel_scene(64, 48, "effects:\n  noise: {std: 0.01, bits: 12}\n");
    let (_a, ds) = run_yaml(&yaml);
    let mut vals = Vec::new();
    for i in 0..ds.frames.len() {
        let img = frame(&ds, i);
        for row in 0..48 {
            for col in 0..64 {
                for b in 0..6 {
                    let v = img.get(row, col, b) as f64;
                    let dn = v * 4095.0;
                    assert!((dn - dn.round()).abs() < 1e-3, "{v} is not a 12-bit level");
                    vals.push(v);
                }
            }
        }
    }
    let n = vals.len() as f64;
    let mean = vals.iter().sum::<f64>() / n;
    let std = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    // 55296 samples: the std is within ~1% of 0.01 (quantisation adds 1/(4095 √12) in quadrature).
    let expect = (0.01f64.powi(2) + (1.0 / 4095.0f64).powi(2) / 12.0).sqrt();
    assert!((mean - 0.4).abs() < 3e-4, "mean {mean}");
    assert!((std / expect - 1.0).abs() < 0.03, "std {std} vs {expect}");
    // Neighbouring pixels are independent.
    let r = vals.windows(7).map(|w| (w[0] - mean) * (w[6] - mean)).sum::<f64>() / (n * std * std);
    assert!(r.abs() < 0.03, "correlation {r}");

    // Shot noise: variance = shot · value.
    let (_b, ds) = run_yaml(&panel_scene(64, 48, "effects:\n  noise: {shot: 0.0004, bits: 0}\n"));
    let img = frame(&ds, 0);
    let v: Vec<f64> =
        (0..48).flat_map(|r| (0..64).map(move |c| (r, c))).map(|(r, c)| img.get(r, c, 3) as f64).collect();
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
    assert!((s / (0.0004f64 * 0.4).sqrt() - 1.0).abs() < 0.06, "shot std {s}");

    // u16 output stores the DNs with pixel_scale 4095 and loads to the same values as f32 output.
    let desc = scene(&yaml);
    let (_c, ds16) = run(&desc, &SimOptions { format: msnerf::sim::PixelFormat::U16, ..Default::default() });
    assert_eq!(ds16.pixel_scale, Some(4095.0));
    let b = frame(&ds16, 0);
    let f32_img = frame(&run(&desc, &SimOptions::default()).1, 0);
    for row in 0..48 {
        for col in 0..64 {
            for k in 0..6 {
                assert!((b.get(row, col, k) - f32_img.get(row, col, k)).abs() < 1e-7);
            }
        }
    }
}

#[test]
fn rig_parallax_moves_a_band_camera_and_writes_its_rig() {
    // The NIR camera sits 2 px worth of ground to the right of the frame camera at view 0's height (50 m): over flat
    // ground its image is the reference image moved 2 px left, exactly; on the 5 m box the parallax is larger.
    let (_p, plain) = run_yaml(&effect_scene(""));
    let fx = plain.frames[0].camera.fx;
    let offset = 2.0 * 50.0 / fx;
    let yaml = format!("effects:\n  rig_parallax:\n    bands: [{{band: nir, offset_m: [{offset}, 0, 0]}}]\n");
    let (t, ds) = run_yaml(&effect_scene(&yaml));
    let rig = ds.rig.as_ref().expect("rig_cameras written and read back");
    let nir = ds.bands.iter().position(|b| b.name.eq_ignore_ascii_case("nir")).expect("nir band");
    assert_eq!(rig.cameras[nir].rig_from_band[0][3], offset);
    for (b, c) in rig.cameras.iter().enumerate().filter(|&(b, _)| b != nir) {
        assert!(c.is_frame_camera(&ds.frames[0].camera), "band {b} is the frame camera");
    }
    let (img, r) = (frame(&ds, 0), frame(&plain, 0));
    let depth = plain.read_depth(0).unwrap().expect("depth map");
    let ground = |row: u32, col: u32| (depth[(row * W + col) as usize] - 50.0 / ray_cos(row, col, fx)).abs() < 1e-3;
    let (mut flat, mut moved) = (0, 0);
    for row in 0..H {
        for col in 0..W - 2 {
            for b in (0..img.bands).filter(|&b| b != nir) {
                assert_eq!(img.get(row, col, b), r.get(row, col, b), "band {b} untouched");
            }
            if ground(row, col) && ground(row, col + 2) {
                let (got, want) = (img.get(row, col, nir), r.get(row, col + 2, nir));
                assert!((got - want).abs() < 1e-5, "flat ground ({row},{col}): {got} vs {want}");
                flat += 1;
                moved += usize::from(img.get(row, col, nir) != r.get(row, col, nir));
            }
        }
    }
    assert!(flat > 300 && moved > 30, "{flat} flat-ground pixels, {moved} changed by the shift");
    // The registered truth is what the frame camera sees in every band: the plain scene's image.
    let reg = msnerf::data::tiff_reader::read_tiff(&t.path().join("ds/truth/registered/view_00000.tif"), 1 << 30)
        .expect("registered truth")
        .raster;
    for row in 0..H {
        for col in 0..W {
            for b in 0..img.bands {
                assert!((reg.get(row, col, b) - r.get(row, col, b)).abs() < 1e-6, "registered truth ({row},{col},{b})");
            }
        }
    }
}

/// The cosine of the angle between pixel (row, col)'s ray and the optical axis of a pinhole camera with focal `fx`.
fn ray_cos(row: u32, col: u32, fx: f64) -> f32 {
    let (x, y) = ((col as f64 + 0.5 - W as f64 / 2.0) / fx, (row as f64 + 0.5 - H as f64 / 2.0) / fx);
    (1.0 / (1.0 + x * x + y * y).sqrt()) as f32
}
