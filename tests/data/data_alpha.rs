//! Ground truth with an alpha channel is composited over the background (nerfstudio's `blend_background`):
//! `gt = c·α + bg·(1 − α)` for straight alpha (PNG, TIFF ExtraSamples 2), `c + bg·(1 − α)` for associated
//! alpha (TIFF ExtraSamples 1), computed here in f64 from the stored samples and compared with what the loader
//! returns. Alpha is never a band.

use crate::data_support;
use std::path::Path;

use data_support::{bands_json, frame, write_transforms, TempDir};
use msnerf::data::{load_dataset, AlphaBackground, DataError, Dataset, LoadOptions};
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::ExtraSamples;

const W: u32 = 4;
const H: u32 = 2;

fn opts(bg: AlphaBackground) -> LoadOptions {
    LoadOptions { alpha_background: bg, ..Default::default() }
}

fn load(dir: &Path, bg: AlphaBackground) -> Dataset {
    load_dataset(dir, &opts(bg)).unwrap_or_else(|e| panic!("{e}"))
}

/// The background value `bg` stands for.
fn bg_value(bg: AlphaBackground) -> f64 {
    match bg {
        AlphaBackground::White => 1.0,
        _ => 0.0,
    }
}

/// Checks every band of every pixel of frame 0 against `expect(pixel, band, background)`.
fn check(ds: &Dataset, bands: usize, bg: AlphaBackground, expect: &dyn Fn(usize, usize, f64) -> f64) {
    let r = ds.read_frame(0).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.bands, bands, "alpha is not a band");
    let mut px = vec![0.0f32; bands];
    for p in 0..(W * H) as usize {
        r.pixel_into(p as u32 / W, p as u32 % W, &mut px);
        for (b, &got) in px.iter().enumerate() {
            let want = expect(p, b, bg_value(bg));
            assert_eq!(got, want as f32, "{bg:?} pixel {p} band {b}");
            assert_eq!(r.get(p as u32 / W, p as u32 % W, b), want as f32);
            assert_eq!(r.band_f32(b)[p], want as f32);
        }
    }
}

/// An RGBA PNG (8-bit, straight alpha) written with the `image` crate: alpha 0 gives the background, alpha 255
/// the colour, alpha 128 (≈ 0.5) the blend; `bands` absent, so the bands are inferred as RGB (alpha is not one).
#[test]
fn rgba_png_is_composited_over_the_background() {
    let td = TempDir::new("alpha_png");
    let alphas = [0u8, 128, 255, 64, 128, 0, 255, 200];
    let mut data = Vec::new();
    for (p, &a) in alphas.iter().enumerate() {
        data.extend([(30 * p) as u8, 250 - (20 * p) as u8, 17 + p as u8, a]);
    }
    for name in ["a.png", "b.png"] {
        image::save_buffer(td.path().join(name), &data, W, H, image::ExtendedColorType::Rgba8).unwrap();
    }
    write_transforms(
        td.path(),
        W,
        H,
        serde_json::json!({}),
        vec![frame("a.png", 0.0, "train"), frame("b.png", 1.0, "eval")],
    );
    let expect = |p: usize, b: usize, bg: f64| {
        let (c, a) = (data[p * 4 + b] as f64 / 255.0, data[p * 4 + 3] as f64 / 255.0);
        c * a + bg * (1.0 - a)
    };
    for bg in [AlphaBackground::Black, AlphaBackground::White] {
        let ds = load(td.path(), bg);
        assert_eq!(ds.bands.iter().map(|b| b.name.as_str()).collect::<Vec<_>>(), ["red", "green", "blue"]);
        assert!(ds.has_alpha);
        check(&ds, 3, bg, &expect);
        let r = ds.read_frame(0).unwrap();
        // alpha 0: exactly the background; alpha 255: exactly the colour.
        assert_eq!(r.get(0, 0, 1), bg_value(bg) as f32);
        assert_eq!(r.get(0, 2, 0), (data[2 * 4] as f64 / 255.0) as f32);
        // A band selection keeps the compositing.
        let mut sel = ds.clone();
        sel.select_bands(&[2, 0]).unwrap();
        let s = sel.read_frame(0).unwrap();
        for p in 0..(W * H) as usize {
            assert_eq!(s.band_f32(0)[p], expect(p, 2, bg_value(bg)) as f32);
            assert_eq!(s.band_f32(1)[p], expect(p, 0, bg_value(bg)) as f32);
        }
    }
    // The model's `random` background in training: refused by name rather than blended with the wrong colour.
    let ds = load(td.path(), AlphaBackground::Refuse);
    let e = ds.read_frame(0).unwrap_err();
    assert!(matches!(e, DataError::InvalidValue { ref key, .. } if key == "rendering.background"), "{e}");
    assert!(e.to_string().contains("a.png") && e.to_string().contains("random"), "{e}");
}

/// The background a model's `rendering.background` asks for (nerfstudio: `last_sample` and, outside training,
/// `random` composite the ground truth over black).
#[test]
fn background_follows_the_model() {
    use msnerf::nerf::config::Background;
    assert_eq!(Background::LastSample.alpha_background(true), AlphaBackground::Black);
    assert_eq!(Background::Black.alpha_background(true), AlphaBackground::Black);
    assert_eq!(Background::White.alpha_background(false), AlphaBackground::White);
    assert_eq!(Background::Random.alpha_background(true), AlphaBackground::Refuse);
    assert_eq!(Background::Random.alpha_background(false), AlphaBackground::Black);
    // A `random` warm-up before `last_sample`: refused in training, black in evaluation.
    let r = msnerf::nerf::config::RenderingConfig { background: Background::LastSample, random_background_steps: 100 };
    assert_eq!(r.alpha_background(true), AlphaBackground::Refuse);
    assert_eq!(r.alpha_background(false), AlphaBackground::Black);
    let r = msnerf::nerf::config::RenderingConfig { random_background_steps: 0, ..r };
    assert_eq!(r.alpha_background(true), AlphaBackground::Black);
}

fn write_dataset(dir: &Path, bytes: &[u8], bands: usize) {
    std::fs::write(dir.join("a.tif"), bytes).unwrap();
    std::fs::write(dir.join("b.tif"), bytes).unwrap();
    write_transforms(
        dir,
        W,
        H,
        serde_json::json!({"bands": bands_json(bands)}),
        vec![frame("a.tif", 0.0, "train"), frame("b.tif", 1.0, "eval")],
    );
}

/// A 4-band 16-bit MinIsBlack TIFF with a fifth sample flagged ExtraSamples = 2 (unassociated alpha): the
/// multispectral case. Alpha 0, 65535 and 32768 (≈ 0.5).
#[test]
fn multispectral_tiff_with_unassociated_alpha() {
    let td = TempDir::new("alpha_tiff16");
    let alphas = [0u16, 32768, 65535, 1000, 32768, 0, 65535, 50000];
    let mut data = Vec::new();
    for (p, &a) in alphas.iter().enumerate() {
        data.extend((0..4).map(|b| (1000 * (p + 1) + 7000 * b) as u16));
        data.push(a);
    }
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::Gray16>(W, H).unwrap();
        img.extra_samples(&[
            ExtraSamples::Unspecified,
            ExtraSamples::Unspecified,
            ExtraSamples::Unspecified,
            ExtraSamples::UnassociatedAlpha,
        ])
        .unwrap();
        img.write_data(&data).unwrap();
    }
    write_dataset(td.path(), buf.get_ref(), 4);
    for bg in [AlphaBackground::Black, AlphaBackground::White] {
        let ds = load(td.path(), bg);
        check(&ds, 4, bg, &|p, b, bg| {
            let (c, a) = (data[p * 5 + b] as f64 / 65535.0, data[p * 5 + 4] as f64 / 65535.0);
            c * a + bg * (1.0 - a)
        });
    }
}

/// A 3-band float TIFF with associated (premultiplied) alpha, ExtraSamples = 1: `c + bg·(1 − α)`, with α = 0,
/// 0.5 and 1 exactly.
#[test]
fn float_tiff_with_associated_alpha() {
    let td = TempDir::new("alpha_tiff_f32");
    let alphas = [0.0f32, 0.5, 1.0, 0.25, 0.5, 0.0, 1.0, 0.75];
    let mut data = Vec::new();
    for (p, &a) in alphas.iter().enumerate() {
        // Premultiplied colour: at most α.
        data.extend((0..3).map(|b| a * (0.1 + 0.1 * p as f32 + 0.05 * b as f32).min(1.0)));
        data.push(a);
    }
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::Gray32Float>(W, H).unwrap();
        img.extra_samples(&[ExtraSamples::Unspecified, ExtraSamples::Unspecified, ExtraSamples::AssociatedAlpha])
            .unwrap();
        img.write_data(&data).unwrap();
    }
    write_dataset(td.path(), buf.get_ref(), 3);
    for bg in [AlphaBackground::Black, AlphaBackground::White] {
        let ds = load(td.path(), bg);
        check(&ds, 3, bg, &|p, b, bg| {
            let (c, a) = (data[p * 4 + b] as f64, data[p * 4 + 3] as f64);
            c + bg * (1.0 - a)
        });
        let r = ds.read_frame(0).unwrap();
        assert_eq!(r.get(0, 0, 0), bg_value(bg) as f32, "alpha 0 is the background");
        assert_eq!(r.get(0, 1, 2), (data[4 + 2] as f64 + 0.5 * bg_value(bg)) as f32, "alpha 0.5");
    }
}

/// Extra samples that are not alpha (ExtraSamples = 0) stay bands, as before.
#[test]
fn unspecified_extra_samples_stay_bands() {
    let td = TempDir::new("alpha_none");
    let data: Vec<u8> = (0..(W * H * 3) as u8).map(|x| x * 9).collect();
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::Gray8>(W, H).unwrap();
        img.extra_samples(&[ExtraSamples::Unspecified, ExtraSamples::Unspecified]).unwrap();
        img.write_data(&data).unwrap();
    }
    write_dataset(td.path(), buf.get_ref(), 3);
    let ds = load(td.path(), AlphaBackground::White);
    assert!(!ds.has_alpha);
    check(&ds, 3, AlphaBackground::White, &|p, b, _| data[p * 3 + b] as f64 / 255.0);
}
