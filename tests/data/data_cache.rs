//! Host image cache: budget respected across resampling, every image visited, paper-scale plan, sampling.

use crate::data_support;
use data_support::TempDir;
use msnerf::data::cache::plan_cache;
use msnerf::data::synth::{synth_value, write_synthetic_dataset, SynthSpec};
use msnerf::data::{load_dataset, CacheConfig, ImageCache, LoadOptions, Split};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

#[test]
fn paper_scale_dataset_fits_16_gb() {
    let per = 1280u64 * 960 * 6 * 2;
    let p = plan_cache(4000, per, 16_000_000_000).unwrap();
    assert_eq!(p.n_resident, (16_000_000_000 / per - 1) as usize);
    assert!(p.peak_bytes <= 16_000_000_000);
    assert!(!p.fits_all && p.n_resident > 1000);
    let all = plan_cache(100, per, 16_000_000_000).unwrap();
    assert!(all.fits_all);
    assert!(plan_cache(10, per, per).is_none());
}

#[test]
fn budget_respected_and_all_images_visited() {
    let td = TempDir::new("cache");
    let spec = SynthSpec { frames: 24, width: 40, height: 30, bands: 6 };
    write_synthetic_dataset(td.path(), &spec).unwrap();
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let train = ds.split_indices(Split::Train);
    assert_eq!(train.len(), 21);
    let per = ds.image_bytes();
    assert_eq!(per, 40 * 30 * 6 * 2);
    let budget = per * 6 + per / 2; // room for 5 resident + scratch
    let cfg = CacheConfig { budget_bytes: budget, resample_every: 10, seed: 3 };
    let mut cache = ImageCache::new(&ds, train.clone(), cfg).unwrap();
    assert_eq!(cache.plan().n_resident, 5);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for step in 0..100 {
        let batch = cache.sample_pixels(&mut rng, 256);
        assert_eq!(batch.values.len(), 256 * 6);
        let resident = cache.resident_frames();
        for k in 0..256 {
            let fi = batch.image[k] as usize;
            assert!(resident.contains(&fi));
            // Values are exactly the stored u16 / 65520 (pixel_scale of the synthetic dataset).
            let (r, c) = (batch.row[k], batch.col[k]);
            for b in 0..6 {
                let raw = synth_value(fi, b, r, c) as f64;
                assert_eq!(batch.values[k * 6 + b], (raw / 65520.0) as f32);
            }
        }
        assert!(cache.current_bytes() <= budget && cache.peak_bytes() <= budget, "step {step}");
        cache.step().unwrap();
    }
    assert_eq!(cache.visited_fraction(), 1.0);
    assert!(cache.peak_bytes() <= budget);
    // Deterministic: the same seed gives the same resident sets.
    let c2 = ImageCache::new(&ds, train, cfg).unwrap();
    let c3 = ImageCache::new(&ds, ds.split_indices(Split::Train), cfg).unwrap();
    assert_eq!(c2.resident_frames(), c3.resident_frames());
}

#[test]
fn masked_pixels_are_rejected() {
    let td = TempDir::new("cmask");
    let spec = SynthSpec { frames: 3, width: 10, height: 8, bands: 2 };
    write_synthetic_dataset(td.path(), &spec).unwrap();
    // Mask out all but column 3 on every frame.
    let mask: Vec<u8> = (0..80).map(|i| if i % 10 == 3 { 255 } else { 0 }).collect();
    image::GrayImage::from_raw(10, 8, mask).unwrap().save(td.path().join("m.png")).unwrap();
    let p = td.path().join("transforms.json");
    let mut j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    for f in j["frames"].as_array_mut().unwrap() {
        f["mask_path"] = serde_json::json!("m.png");
        f["split"] = serde_json::json!("train");
    }
    std::fs::write(&p, j.to_string()).unwrap();
    let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap();
    let cfg = CacheConfig { budget_bytes: 1 << 20, resample_every: 0, seed: 1 };
    let cache = ImageCache::new(&ds, ds.split_indices(Split::Train), cfg).unwrap();
    assert!(cache.plan().fits_all);
    let b = cache.sample_pixels(&mut ChaCha8Rng::seed_from_u64(2), 500);
    assert!(b.col.iter().all(|&c| c == 3));
    assert!(b.mask.iter().all(|&m| m == 1));
    // Uniform over rows of the valid column: every row appears.
    for r in 0..8 {
        assert!(b.row.contains(&r));
    }
}
