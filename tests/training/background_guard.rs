//! The two guards against a run that trains into nothing (`msnerf::nerf::background_guard`), on loss sequences and
//! pixels built here: a collapse after the random warm-up is caught and re-warmed (and, after three, the random
//! background stays), an ordinary run is left alone; the constant-colour PSNR equals a plain f64 computation of the
//! best constant per band.

use msnerf::nerf::background_guard::{constant_psnr, BackgroundGuard, MAX_REWARMS, REWARM_STEPS, WINDOW};
use msnerf::nerf::config::{Background, RenderingConfig};

fn cfg(steps: u64, background: Background) -> RenderingConfig {
    RenderingConfig { background, random_background_steps: steps }
}

#[test]
fn a_collapse_after_the_warm_up_is_rewarmed_and_an_ordinary_run_is_left_alone() {
    assert!(BackgroundGuard::new(&cfg(0, Background::LastSample)).is_none(), "no warm-up, nothing to guard");
    assert!(BackgroundGuard::new(&cfg(300, Background::Random)).is_none(), "random throughout, nothing to guard");

    // An ordinary run: the loss keeps falling through the switch.
    let mut g = BackgroundGuard::new(&cfg(300, Background::LastSample)).unwrap();
    for step in 0..1000u64 {
        assert_eq!(g.observe(step, 3e-3 / (1.0 + step as f64 / 200.0), 1e-4), None, "step {step}");
    }
    assert!(g.notes.is_empty());

    // A dip after the switch that recovers: the colour loss doubles for 300 steps but the weights stay on a surface
    // (the distortion loss keeps its size), as a flight-rural run did before reaching 34 dB. Left alone.
    let mut g = BackgroundGuard::new(&cfg(300, Background::LastSample)).unwrap();
    for step in 0..1200u64 {
        let (rgb, dist) = match step {
            0..300 => (7.7e-3, 9e-5),
            300..600 => (1.7e-2, 6e-5),
            _ => (4e-4, 4e-5),
        };
        assert_eq!(g.observe(step, rgb, dist), None, "step {step}");
    }

    // A collapse at the switch (the flight-rural seed that failed: colour loss 2.8e-3 -> 5.7e-3, the distortion
    // loss from 1e-4 to 0: no weight on any surface, for good).
    let mut g = BackgroundGuard::new(&cfg(300, Background::LastSample)).unwrap();
    let mut asked = Vec::new();
    let mut switch = 300u64;
    for step in 0..5000u64 {
        let collapsed = step >= switch;
        let (rgb, dist) = if collapsed { (5.7e-3, 0.0) } else { (2.8e-3, 1e-4) };
        if let Some(end) = g.observe(step, rgb, dist) {
            asked.push((step, end));
            switch = end;
        }
    }
    assert_eq!(asked.len(), MAX_REWARMS as usize, "{asked:?}");
    let (first, end) = asked[0];
    assert!((300..300 + 2 * WINDOW as u64).contains(&first), "caught within the window after the switch: {first}");
    assert_eq!(end, first + 1 + REWARM_STEPS);
    assert_eq!(asked.last().unwrap().1, u64::MAX, "after {MAX_REWARMS} collapses the random background stays");
    assert_eq!(g.notes.len(), MAX_REWARMS as usize);
    assert!(g.notes[0].contains("turned transparent"), "{}", g.notes[0]);

    // A few noisy steps after the switch (a transparent moment the window does not see as one) are left alone.
    let mut g = BackgroundGuard::new(&cfg(300, Background::LastSample)).unwrap();
    for step in 0..600u64 {
        let spike = (300..305).contains(&step);
        assert_eq!(
            g.observe(step, if spike { 6e-3 } else { 2.8e-3 }, if spike { 0.0 } else { 1e-4 }),
            None,
            "step {step}"
        );
    }
}

#[test]
fn the_constant_colour_psnr_is_the_best_constant_per_band() {
    // Two bands, weighted pixels, one NaN left out.
    let pixels: [[f64; 3]; 5] =
        [[0.1, 0.5, 1.0], [0.3, 0.4, 1.0], [0.2, f64::NAN, 2.0], [0.6, 0.45, 0.5], [0.05, 0.55, 1.0]];
    let targets: Vec<f32> = pixels.iter().flat_map(|p| p.map(|v| v as f32)).collect();
    // Plain f64: per band the weighted mean is the best constant; its weighted squared error over all values.
    let (mut sq, mut count) = (0.0, 0.0);
    for k in 0..2 {
        let vals: Vec<(f64, f64)> = pixels.iter().filter(|p| !p[k].is_nan()).map(|p| (p[k], p[2])).collect();
        let w: f64 = vals.iter().map(|v| v.1).sum();
        let m = vals.iter().map(|v| v.0 * v.1).sum::<f64>() / w;
        sq += vals.iter().map(|v| v.1 * (v.0 - m).powi(2)).sum::<f64>();
        count += w;
    }
    let want = -10.0 * (sq / count).log10();
    let got = constant_psnr(&targets, 2).unwrap();
    assert!((got - want).abs() < 1e-5, "{got} against {want}");
    assert_eq!(constant_psnr(&[], 2), None);
}
