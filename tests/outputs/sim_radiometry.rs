//! Radiometry of the simulator: band integration, flat Lambertian light, sun + sky with cast shadows, and the
//! vegetation BRDF, each against its documented formula (src/sim/effects.rs, src/sim/spectra.rs).

use crate::sim_support;
use msnerf::sim::spectra::{band_value, fwhm_to_sigma, Response, Spectrum};
use sim_support::*;

fn gauss(c: f64, w: f64) -> Response {
    Response::Gaussian { center_nm: c, fwhm_nm: w }
}

/// Standard normal CDF (Abramowitz-Stegun 7.1.26 erf, |error| < 1.5e-7).
fn phi(x: f64) -> f64 {
    let z = x.abs() / 2f64.sqrt();
    let t = 1.0 / (1.0 + 0.3275911 * z);
    let y = 1.0
        - (((((1.061405429 * t - 1.453152027) * t) + 1.421413741) * t - 0.284496736) * t + 0.254829592)
            * t
            * (-z * z).exp();
    if x >= 0.0 {
        0.5 * (1.0 + y)
    } else {
        0.5 * (1.0 - y)
    }
}

#[test]
fn flat_spectrum_gives_exactly_its_value_in_every_band() {
    for r in [0.0, 0.05, 0.1234567, 0.4, 0.9, 1.0] {
        let s = Spectrum::flat(r);
        let knots = Spectrum::new(vec![(400.0, r), (650.0, r), (900.0, r)]).unwrap();
        for resp in [
            gauss(450.0, 35.0),
            gauss(720.0, 10.0),
            gauss(840.0, 30.0),
            gauss(401.0, 3.0),
            Response::Table(vec![(500.0, 0.0), (520.0, 1.0), (560.0, 0.7), (600.0, 0.0)]),
        ] {
            assert_eq!(band_value(&s, &resp), r, "{resp:?}");
            assert_eq!(band_value(&knots, &resp), r, "{resp:?}");
        }
    }
}

#[test]
fn step_spectrum_gives_the_gaussian_fraction() {
    // r = 0 below the step, 1 above (a 1e-4 nm ramp): the band value is the response weight above the step.
    let step = |at: f64| Spectrum::new(vec![(at - 5e-5, 0.0), (at + 5e-5, 1.0)]).unwrap();
    for (c, w) in [(660.0, 22.0), (840.0, 30.0), (720.0, 10.0)] {
        let s = fwhm_to_sigma(w);
        for k in [-2.0, -1.0, -0.5, 0.0, 0.3, 1.0, 1.5] {
            let v = band_value(&step(c + k * s), &gauss(c, w));
            let expect = 1.0 - phi(k);
            assert!((v - expect).abs() < 1e-3, "c {c} w {w} step at {k} sigma: {v} vs {expect}");
        }
    }
    // Box-shaped table response 500..600 nm: a step at 525 leaves 3/4 of the weight above it.
    let boxr = Response::Table(vec![(500.0, 1.0), (600.0, 1.0)]);
    assert!((band_value(&step(525.0), &boxr) - 0.75).abs() < 1e-3);
    assert!((band_value(&step(550.0), &boxr) - 0.5).abs() < 1e-3);
    // A linear spectrum is integrated exactly enough: mean over a symmetric band = value at the centre.
    let lin = Spectrum::new(vec![(400.0, 0.0), (900.0, 1.0)]).unwrap();
    assert!((band_value(&lin, &gauss(650.0, 40.0)) - 0.5).abs() < 1e-9);
}

#[test]
fn flat_lambertian_panel_reads_its_reflectance_exactly() {
    // No effects: every pixel of every band is the band reflectance of the surface.
    let (_t, ds) = run_yaml(&panel_scene(32, 24, ""));
    assert_eq!(ds.n_bands(), 6);
    for i in 0..ds.frames.len() {
        let r = frame(&ds, i);
        for row in 0..24 {
            for col in 0..32 {
                for b in 0..6 {
                    assert_eq!(r.get(row, col, b), 0.4f32, "frame {i} ({row},{col}) band {b}");
                }
            }
        }
    }
    // A spectral material reads its band integration.
    let yaml = panel_scene(16, 12, "").replace("ground: {material: panel", "ground: {material: leaves");
    let (_t, ds) = run_yaml(&yaml);
    let leaves = Spectrum::new(vec![
        (400.0, 0.03),
        (500.0, 0.05),
        (550.0, 0.09),
        (660.0, 0.04),
        (700.0, 0.10),
        (740.0, 0.35),
        (800.0, 0.46),
        (900.0, 0.47),
    ])
    .unwrap();
    let r = frame(&ds, 0);
    for (b, band) in ds.bands.iter().enumerate() {
        let expect = band_value(&leaves, &gauss(band.center_nm.unwrap(), band.fwhm_nm.unwrap())) as f32;
        assert_eq!(r.get(5, 7, b), expect, "band {}", band.name);
    }
    // Red edge: NIR well above red.
    assert!(r.get(0, 0, 5) > 5.0 * r.get(0, 0, 2));
}

/// Slab test of the ray p + t·s (t > 0) against the box [lo, hi].
fn hits_box(p: [f64; 3], s: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> bool {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        if s[k] == 0.0 {
            if p[k] < lo[k] || p[k] > hi[k] {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo[k] - p[k]) / s[k], (hi[k] - p[k]) / s[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
}

#[test]
fn sun_and_sky_follow_the_formula_with_cast_shadows() {
    let f = 0.2;
    let el: f64 = 45.0;
    let yaml = format!(
        "name: sun\nimage: {{width: 96, height: 72}}\n{MATERIALS}\nground: {{material: panel, extent: 1000}}\n\
boxes:\n  - {{center: [0, 0], size: [6, 6, 10], material: wall, roof: roof}}\n\
cameras:\n  - poses:\n      - {{position: [-5, 0, 60], look_at: [-5, 0, 0], up: [0, 1, 0]}}\n      - {{position: [25, 12, 25], look_at: [0, 0, 3]}}\n\
effects:\n  sun: {{azimuth_deg: 90, elevation_deg: {el}, sky_fraction: {f}}}\n"
    );
    let (_t, ds) = run_yaml(&yaml);
    let s = [el.to_radians().cos(), 0.0, el.to_radians().sin()];
    // (lit ground, shadowed ground, roof, sunlit east wall, west/north/south walls)
    let mut counts = [0usize; 5];
    let (mut lit_sum, mut shadow_sum) = (0.0, 0.0);
    for i in 0..ds.frames.len() {
        let fr = &ds.frames[i];
        let img = frame(&ds, i);
        let depth = ds.read_depth(i).unwrap().unwrap();
        for row in 0..ds.height {
            for col in 0..ds.width {
                let ray = fr.camera.ray_f64(&fr.c2w, row, col);
                let t = depth[(row * ds.width + col) as usize] as f64;
                let p = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k]);
                let (expect, class) = if p[2].abs() < 1e-3 {
                    let outer = hits_box(p, s, [-3.05, -3.05, 0.0], [3.05, 3.05, 10.05]);
                    let inner = hits_box(p, s, [-2.95, -2.95, 0.0], [2.95, 2.95, 9.95]);
                    match (inner, outer) {
                        (true, true) => (0.4 * f, 1),
                        (false, false) => (0.4 * ((1.0 - f) + f), 0),
                        _ => continue,
                    }
                } else if (p[2] - 10.0).abs() < 1e-3 {
                    (0.3 * ((1.0 - f) + f), 2)
                } else if (p[0] - 3.0).abs() < 1e-3 {
                    // n = +x: cos i = cos(el); sky view factor 1/2.
                    (0.25 * ((1.0 - f) * s[0] / s[2] + f * 0.5), 3)
                } else if (p[0] + 3.0).abs() < 1e-3 || (p[1].abs() - 3.0).abs() < 1e-3 {
                    (0.25 * f * 0.5, 4)
                } else {
                    panic!("pixel ({row},{col}) of frame {i} hit nothing known at {p:?}");
                };
                counts[class] += 1;
                for b in 0..6 {
                    let v = img.get(row, col, b) as f64;
                    assert!((v - expect).abs() < 1e-6, "class {class} frame {i} ({row},{col}): {v} vs {expect}");
                }
                match class {
                    0 => lit_sum += img.get(row, col, 0) as f64,
                    1 => shadow_sum += img.get(row, col, 0) as f64,
                    _ => {}
                }
            }
        }
    }
    assert!(counts.iter().all(|&c| c > 20), "every class seen: {counts:?}");
    // The shadow darkens by exactly the sky fraction.
    let ratio = (shadow_sum / counts[1] as f64) / (lit_sum / counts[0] as f64);
    assert!((ratio - f).abs() < 1e-6, "shadow/lit = {ratio}");
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// RPV(k, Θ, ρc) over a horizontal surface with light from `l`, viewer at `v`, relative to nadir/zenith.
fn rpv(k: f64, th: f64, rc: f64, l: [f64; 3], v: [f64; 3]) -> f64 {
    let f = |ci: f64, cv: f64, cg: f64, g: f64| {
        (ci * cv).powf(k - 1.0) / (ci + cv).powf(1.0 - k) * (1.0 - th * th) / (1.0 + 2.0 * th * cg + th * th).powf(1.5)
            * (1.0 + (1.0 - rc) / (1.0 + g))
    };
    let (ci, cv) = (l[2], v[2]);
    let (ti, tv) = ((1.0 - ci * ci).sqrt() / ci, (1.0 - cv * cv).sqrt() / cv);
    let phi = if ti > 0.0 && tv > 0.0 {
        let (hl, hv) = ([l[0], l[1]], [v[0], v[1]]);
        ((hl[0] * hv[0] + hl[1] * hv[1]) / ((hl[0].hypot(hl[1])) * hv[0].hypot(hv[1]))).clamp(-1.0, 1.0)
    } else {
        1.0
    };
    let g = (ti * ti + tv * tv - 2.0 * ti * tv * phi).max(0.0).sqrt();
    f(ci, cv, dot(l, v), g) / f(1.0, 1.0, 1.0, 0.0)
}

#[test]
fn vegetation_brdf_follows_rpv_on_vegetation_only() {
    let base = format!(
        "name: brdf\nimage: {{width: 48, height: 36}}\n{MATERIALS}\nground: {{material: leaves, extent: 1000}}\n\
regions:\n  - {{material: panel, rect: {{center: [0, 0], size: [6, 6]}}}}\n\
cameras:\n  - poses:\n      - {{position: [0, -40, 30], look_at: [0, 0, 0]}}\n      - {{position: [0, 0, 50], look_at: [0, 0, 0], up: [0, 1, 0]}}\n"
    );
    let (k, th, rc) = (0.7, -0.15, 0.25);
    let on = format!("{base}effects:\n  vegetation_brdf: {{k: {k}, theta: {th}, rho_c: {rc}}}\n");
    let (_a, plain) = run_yaml(&base);
    let (_b, ds) = run_yaml(&on);
    let (mut n_veg, mut n_panel, mut max_f, mut min_f) = (0, 0, 0f64, f64::MAX);
    for i in 0..ds.frames.len() {
        let fr = &ds.frames[i];
        let (img, ref_img) = (frame(&ds, i), frame(&plain, i));
        let depth = ds.read_depth(i).unwrap().unwrap();
        for row in 0..ds.height {
            for col in 0..ds.width {
                let ray = fr.camera.ray_f64(&fr.c2w, row, col);
                let t = depth[(row * ds.width + col) as usize] as f64;
                let p = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k]);
                if p[0].abs() < 3.01 && p[1].abs() < 3.01 {
                    if p[0].abs() < 2.99 && p[1].abs() < 2.99 {
                        n_panel += 1;
                        for b in 0..6 {
                            assert_eq!(img.get(row, col, b), 0.4f32, "non-vegetation is untouched");
                        }
                    }
                    continue;
                }
                let v = ray.direction.map(|x| -x);
                let factor = rpv(k, th, rc, [0.0, 0.0, 1.0], v);
                max_f = max_f.max(factor);
                min_f = min_f.min(factor);
                n_veg += 1;
                for b in 0..6 {
                    let expect = ref_img.get(row, col, b) as f64 * factor;
                    let got = img.get(row, col, b) as f64;
                    assert!(
                        (got - expect).abs() < 1e-6 * expect.max(1e-3) + 1e-7,
                        "({row},{col}) b{b}: {got} vs {expect}"
                    );
                }
            }
        }
    }
    assert!(n_veg > 1000 && n_panel > 20, "{n_veg} {n_panel}");
    // Under zenith light the nadir view is the hot spot (factor 1 at the nadir point, which the panel covers here) and
    // oblique views are darker: the factor spans a real range.
    assert!(max_f <= 1.0 + 1e-9 && max_f > 0.95 && min_f < 0.8, "factor range {min_f}..{max_f}");
}

/// Albedo texture (issue 18): off unless a material asks for it; on, each pixel is the material's reflectance times
/// f(p) = max(0, 1 + c n(p)) with n in [-1, 1] fractal value noise of the hit point, the same factor in every band
/// (band ratios, hence indices, unchanged), deterministic, and spatially smooth (the pattern is a property of the
/// surface, so two views of one ground point see one value: checked here through the factor function itself).
#[test]
fn texture_multiplies_every_band_alike_and_is_a_property_of_the_surface() {
    use msnerf::sim::texture::TextureDesc;
    let tex = "  panel: {flat: 0.4, texture: {scale: 4.0, contrast: 0.3}}";
    let yaml = panel_scene(32, 24, "").replace("  panel: {flat: 0.4}", tex);
    assert!(yaml.contains("texture"), "the panel material is textured");
    let (_t, ds) = run_yaml(&yaml);
    let (mut lo, mut hi) = (f32::MAX, f32::MIN);
    for i in 0..ds.frames.len() {
        let r = frame(&ds, i);
        for row in 0..24 {
            for col in 0..32 {
                let v0 = r.get(row, col, 0);
                for b in 1..6 {
                    assert_eq!(r.get(row, col, b), v0, "flat material: every band gets the same factor");
                }
                lo = lo.min(v0);
                hi = hi.max(v0);
            }
        }
    }
    assert!(lo >= 0.4 * 0.7 - 1e-6 && hi <= 0.4 * 1.3 + 1e-6, "within 1 +- contrast: {lo} .. {hi}");
    assert!(hi - lo > 0.04, "the texture varies across the images: {lo} .. {hi}");
    // The factor itself: deterministic, within bounds, mean near 1, smooth below its finest octave, seed-dependent.
    let t = TextureDesc { scale: 4.0, contrast: 0.3, octaves: 3 };
    let (mut sum, mut n, mut max_step) = (0.0, 0, 0.0f64);
    for i in 0..2000 {
        let p = [i as f64 * 0.37 - 300.0, (i * 7 % 113) as f64 * 0.91, 0.0];
        let f = t.factor(5, 2, p);
        assert_eq!(f, t.factor(5, 2, p), "deterministic");
        assert!((0.7..=1.3).contains(&f), "{f}");
        let g = t.factor(5, 2, [p[0] + 0.01, p[1], p[2]]);
        max_step = max_step.max((f - g).abs());
        sum += f;
        n += 1;
    }
    assert!((sum / n as f64 - 1.0).abs() < 0.05, "mean factor {}", sum / n as f64);
    assert!(max_step < 0.02, "smooth at 1 cm: largest change {max_step}");
    assert_ne!(t.factor(5, 2, [1.3, 2.7, 0.0]), t.factor(6, 2, [1.3, 2.7, 0.0]), "the seed changes the pattern");
    // Bad values name the key.
    let bad = panel_scene(8, 6, "")
        .replace("  panel: {flat: 0.4}", "  panel: {flat: 0.4, texture: {scale: 0, contrast: 0.3}}");
    let err = msnerf::sim::SceneDesc::from_yaml(&bad, "test.yaml").expect_err("scale 0").to_string();
    assert!(err.contains("materials.panel.texture.scale"), "{err}");
}
