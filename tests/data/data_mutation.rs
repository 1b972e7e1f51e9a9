//! Thousands of seeded corruptions (bit flips, truncations, byte insertions) of TIFF, EXR and JSON inputs:
//! the readers and the loader must return errors, never panic.

use crate::data_support;
use std::panic::{catch_unwind, AssertUnwindSafe};

use data_support::*;
use msnerf::data::reader::read_image_bytes;
use msnerf::data::{load_dataset, LoadOptions};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn mutate(rng: &mut ChaCha8Rng, src: &[u8]) -> Vec<u8> {
    let mut b = src.to_vec();
    for _ in 0..rng.random_range(1..4) {
        if b.is_empty() {
            break;
        }
        match rng.random_range(0..4) {
            0 | 1 => {
                let i = rng.random_range(0..b.len());
                b[i] ^= 1 << rng.random_range(0..8);
            }
            2 => {
                let n = rng.random_range(0..b.len());
                b.truncate(n);
            }
            _ => {
                let i = rng.random_range(0..=b.len());
                let n = rng.random_range(1..8);
                for _ in 0..n {
                    b.insert(i, rng.random());
                }
            }
        }
    }
    b
}

fn exr_bytes() -> Vec<u8> {
    use exr::prelude::*;
    let ch: Vec<AnyChannel<FlatSamples>> = ["a", "b"]
        .iter()
        .map(|n| AnyChannel::new(*n, FlatSamples::F16((0..96).map(|i| f16::from_f32(i as f32)).collect())))
        .collect();
    let img = Image::from_channels((12, 8), AnyChannels::sort(ch.into()));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write().to_buffered(&mut out).unwrap();
    out.into_inner()
}

#[test]
fn corrupted_images_never_panic() {
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    for (planar, tiles, lzw, pred, kind) in [
        (false, None, false, 1, Kind::U16),
        (true, Some((16, 16)), false, 2, Kind::U16),
        (false, Some((16, 16)), true, 3, Kind::F32),
        (false, None, true, 2, Kind::U8),
    ] {
        let mut s = TiffSpec::new(20, 18, 3, kind);
        s.planar = planar;
        s.tiles = tiles;
        s.lzw = lzw;
        s.predictor = pred;
        seeds.push(tiff_bytes(&s));
    }
    let mut s = TiffSpec::new(20, 18, 3, Kind::U16);
    s.pages = true;
    seeds.push(tiff_bytes(&s));
    seeds.push(exr_bytes());
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let mut errors = 0;
    let n = 6000;
    for i in 0..n {
        let src = &seeds[i % seeds.len()];
        let b = mutate(&mut rng, src);
        let r = catch_unwind(AssertUnwindSafe(|| read_image_bytes(&b, 1 << 22)));
        match r {
            Ok(Err(_)) => errors += 1,
            Ok(Ok(d)) => {
                assert!(d.raster.samples.len() == d.raster.width as usize * d.raster.height as usize * d.raster.bands)
            }
            Err(_) => panic!("panic escaped the reader on mutation {i} of seed {}", i % seeds.len()),
        }
    }
    assert!(errors > n / 10, "too few corruptions detected: {errors}");
}

#[test]
fn corrupted_json_and_images_through_the_loader_never_panic() {
    let td = TempDir::new("mut");
    let tif = tiff_bytes(&TiffSpec::new(8, 6, 2, Kind::U16));
    write_transforms(
        td.path(),
        8,
        6,
        serde_json::json!({"bands": bands_json(2), "k1": 0.01}),
        vec![frame("a.tif", 0.0, "train"), frame("b.tif", 1.0, "train")],
    );
    let json = std::fs::read(td.path().join("transforms.json")).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for i in 0..1500 {
        let j = if i % 3 == 0 { json.clone() } else { mutate(&mut rng, &json) };
        std::fs::write(td.path().join("transforms.json"), &j).unwrap();
        std::fs::write(td.path().join("a.tif"), mutate(&mut rng, &tif)).unwrap();
        std::fs::write(td.path().join("b.tif"), &tif).unwrap();
        let r = catch_unwind(AssertUnwindSafe(|| {
            if let Ok(ds) = load_dataset(td.path(), &LoadOptions::default()) {
                for k in 0..ds.frames.len() {
                    let _ = ds.read_frame(k);
                }
            }
            let _ = msnerf::data::check_dataset(td.path(), 1 << 20);
        }));
        assert!(r.is_ok(), "panic on loader mutation {i}");
    }
}
