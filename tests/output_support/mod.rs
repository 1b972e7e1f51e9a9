//! Helpers shared by the tests/output_*.rs files: a scratch folder per test and small builders.
#![allow(dead_code)]

use std::path::PathBuf;

use msnerf::output::image::{band, ms600pro_bands};
use msnerf::output::{Band, SpectralImage};

/// A fresh folder under the system temp dir, unique per test name and process.
pub fn scratch(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("msnerf-out-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create scratch dir");
    d
}

/// A deterministic 6-band MS600Pro-like image: smooth patterns with distinct values per band.
pub fn six_band(w: usize, h: usize) -> SpectralImage {
    let bands = ms600pro_bands();
    let mut data = Vec::with_capacity(w * h * 6);
    for b in 0..6 {
        for y in 0..h {
            for x in 0..w {
                let v =
                    0.05 + 0.1 * b as f32 + 0.3 * ((x as f32 * 0.37 + y as f32 * 0.11 + b as f32).sin() * 0.5 + 0.5);
                data.push(v);
            }
        }
    }
    SpectralImage::from_planar(w, h, bands, data).expect("valid shape")
}

pub fn bands_named(names: &[(&str, Option<f64>)]) -> Vec<Band> {
    names.iter().map(|&(n, c)| band(n, c, None)).collect()
}

/// A tiny deterministic generator (xorshift) for test data without extra crates.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}
