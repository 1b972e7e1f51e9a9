//! Two guards against a run that trains into nothing in silence (docs/geometry.md, "A transparent field"):
//!
//! - [`BackgroundGuard`]: after the `random` warm-up (`rendering.random_background_steps`) the `last_sample`
//!   background lets a field that stays transparent cost nothing, and on some flights and seeds the field collapses
//!   right at the switch: every ray's weight moves behind the ground, the distortion loss falls to 0 and the colour
//!   loss doubles within a hundred steps, then stays (issue 50's bisection of the importer's keys was this, not a
//!   key; docs/results/flight.md, "Training into nothing"). A switch is often followed
//!   by a dip that recovers within a few hundred steps (the colour loss doubles too, but the weights stay on a
//!   surface: the distortion loss keeps its size), which must be left alone. So the guard compares the
//!   [`WINDOW`] steps after the switch with the [`WINDOW`] steps before it, over the [`WATCH`] steps after it: the
//!   colour loss up by [`COLLAPSE_RATIO`] *and* the distortion loss down to [`TRANSPARENT_RATIO`] of its size is a
//!   collapse, and the warm-up is extended by [`REWARM_STEPS`] (the field turns opaque again under the random
//!   background), up to [`MAX_REWARMS`] times, after which the random background stays for the rest of the run.
//!   Every re-warm is logged and recorded in the run's summary.
//! - [`constant_psnr`]: the held-out PSNR a constant colour per band scores on the same pixels; a run whose best
//!   held-out PSNR stays within [`NOTHING_LEARNT_DB`] of it learnt little of the scene, and says so; targets below
//!   [`SMALL_VALUES`] in every band (radiance rather than reflectance) are named as the likely reason.

use std::collections::VecDeque;

use super::config::{Background, RenderingConfig};

/// Steps compared before and after the switch.
pub const WINDOW: usize = 40;
/// A colour loss this many times the warm-up's, with a distortion loss below [`TRANSPARENT_RATIO`] of the warm-up's,
/// is a collapse.
pub const COLLAPSE_RATIO: f64 = 1.5;
/// The distortion loss of a transparent field (no weight on any surface) relative to the warm-up's.
pub const TRANSPARENT_RATIO: f64 = 0.1;
/// Steps of `random` background added after a collapse.
pub const REWARM_STEPS: u64 = 300;
/// Re-warms before the random background stays.
pub const MAX_REWARMS: u32 = 3;
/// Steps after a switch during which a collapse is looked for.
pub const WATCH: u64 = 400;

/// Watches the switch from the random warm-up to `background`.
#[derive(Debug, Clone)]
pub struct BackgroundGuard {
    /// The step the warm-up ends at (the configuration's, then each re-warm's).
    pub switch_at: u64,
    /// (colour loss, distortion loss) of the last steps before and after the switch.
    before: VecDeque<(f64, f64)>,
    after: VecDeque<(f64, f64)>,
    pub rewarms: u32,
    /// What the guard did, one line each.
    pub notes: Vec<String>,
}

impl BackgroundGuard {
    /// A guard for `cfg` when it has a warm-up before a non-random background; None otherwise.
    pub fn new(cfg: &RenderingConfig) -> Option<BackgroundGuard> {
        (cfg.random_background_steps > 0 && cfg.background != Background::Random).then(|| BackgroundGuard {
            switch_at: cfg.random_background_steps,
            before: VecDeque::with_capacity(WINDOW),
            after: VecDeque::with_capacity(WINDOW),
            rewarms: 0,
            notes: Vec::new(),
        })
    }

    /// Feeds the colour and distortion losses of completed step `step` (in order). Returns the new end of the
    /// warm-up when the field collapsed after the switch.
    pub fn observe(&mut self, step: u64, loss_rgb: f64, loss_distortion: f64) -> Option<u64> {
        if !(loss_rgb.is_finite() && loss_distortion.is_finite()) {
            return None;
        }
        let losses = (loss_rgb, loss_distortion);
        if step < self.switch_at {
            if self.before.len() == WINDOW {
                self.before.pop_front();
            }
            self.before.push_back(losses);
            return None;
        }
        if step >= self.switch_at + WATCH || self.before.len() < WINDOW / 2 {
            return None;
        }
        if self.after.len() == WINDOW {
            self.after.pop_front();
        }
        self.after.push_back(losses);
        if self.after.len() < WINDOW {
            return None;
        }
        let mean = |v: &VecDeque<(f64, f64)>| {
            let n = v.len() as f64;
            (v.iter().map(|x| x.0).sum::<f64>() / n, v.iter().map(|x| x.1).sum::<f64>() / n)
        };
        let ((b, bd), (a, ad)) = (mean(&self.before), mean(&self.after));
        if a <= COLLAPSE_RATIO * b || ad >= TRANSPARENT_RATIO * bd {
            return None;
        }
        self.rewarms += 1;
        self.after.clear();
        self.before.clear();
        let end = if self.rewarms >= MAX_REWARMS { u64::MAX } else { step + 1 + REWARM_STEPS };
        let what = if end == u64::MAX {
            "the random background stays for the rest of the run".to_string()
        } else {
            format!("random background again until step {end}")
        };
        self.notes.push(format!(
            "step {step}: the field turned transparent after the switch to the {} background (colour loss {b:.3e} -> \
             {a:.3e}, distortion loss {bd:.2e} -> {ad:.2e}): {what}",
            "last_sample"
        ));
        self.switch_at = end;
        Some(end)
    }
}

/// A held-out PSNR less than this above [`constant_psnr`] means the field predicts held-out views no better than
/// a constant colour per band: it learnt little of the scene.
pub const NOTHING_LEARNT_DB: f64 = 1.0;

/// Targets whose 99th percentile stays below this in every band are small for the colour head's sigmoid (its
/// gradient near 0 is a few percent of its gradient at 0.5): radiance in W/(m² sr nm) trains several times slower
/// than reflectance of the same scene.
pub const SMALL_VALUES: f64 = 0.2;

/// The largest per-band 99th percentile of `targets` (`bands + 1` values per pixel, the last the weight).
pub fn band_p99_max(targets: &[f32], bands: usize) -> Option<f64> {
    let n = targets.len() / (bands + 1);
    (0..bands)
        .filter_map(|k| {
            let mut v: Vec<f64> =
                (0..n).map(|i| targets[i * (bands + 1) + k] as f64).filter(|x| x.is_finite()).collect();
            if v.is_empty() {
                return None;
            }
            v.sort_by(f64::total_cmp);
            Some(v[((v.len() - 1) as f64 * 0.99).round() as usize])
        })
        .reduce(f64::max)
}

/// The PSNR (data range 1) of the best constant colour per band on the weighted targets `targets` (`bands + 1`
/// values per pixel: the bands, then the pixel's weight; NaN band values are left out), as
/// [`super::trainer::eval_psnr`] weighs them.
pub fn constant_psnr(targets: &[f32], bands: usize) -> Option<f64> {
    let n = targets.len() / (bands + 1);
    let (mut sq, mut count) = (0.0f64, 0.0f64);
    for k in 0..bands {
        let (mut sw, mut swy, mut swyy) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..n {
            let w = targets[i * (bands + 1) + bands] as f64;
            let y = targets[i * (bands + 1) + k] as f64;
            if !y.is_nan() {
                sw += w;
                swy += w * y;
                swyy += w * y * y;
            }
        }
        if sw > 0.0 {
            sq += swyy - swy * swy / sw;
            count += sw;
        }
    }
    (count > 0.0).then(|| -10.0 * (sq / count).max(1e-20).log10())
}
