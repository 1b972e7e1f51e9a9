//! Implausible camera centres: a GPS glitch or a typo puts one camera kilometres (or 1e300 units) from the
//! others, and nerfstudio-style normalisation then squeezes the real scene into a point. Detected robustly, from
//! the median centre and the median distance to it (not min/max, which the outlier itself defines): a centre
//! farther than [`OUTLIER_FACTOR`] times the median distance is an outlier. Needs at least
//! [`MIN_FRAMES_FOR_OUTLIERS`] frames; with all cameras at one point (spread 0) nothing is flagged there.

use super::loader::Frame;

/// How many median distances from the median centre make an outlier. A regular flight grid or an orbit has
/// all its centres within about 2-3 median distances, a straight corridor within 2.
pub const OUTLIER_FACTOR: f64 = 10.0;
pub const MIN_FRAMES_FOR_OUTLIERS: usize = 5;

/// An outlying camera: its frame's position in `frames`, its distance to the median centre and the median distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outlier {
    pub frame: usize,
    pub distance: f64,
    pub spread: f64,
}

fn median(v: Vec<f64>) -> f64 {
    crate::util::stats::upper_median(&v)
}

/// The outlying cameras of `frames` (in the dataset's own world units).
pub fn outlier_cameras(frames: &[Frame]) -> Vec<Outlier> {
    if frames.len() < MIN_FRAMES_FOR_OUTLIERS {
        return Vec::new();
    }
    let centre = |f: &Frame| [f.c2w[0][3], f.c2w[1][3], f.c2w[2][3]];
    let m: [f64; 3] = std::array::from_fn(|k| median(frames.iter().map(|f| centre(f)[k]).collect()));
    // Distances scaled before squaring so 1e300 stays finite (hypot in 3-D).
    let dist = |c: [f64; 3]| {
        let d = [c[0] - m[0], c[1] - m[1], c[2] - m[2]];
        d[0].hypot(d[1]).hypot(d[2])
    };
    let d: Vec<f64> = frames.iter().map(|f| dist(centre(f))).collect();
    let spread = median(d.clone());
    if spread <= 0.0 || !spread.is_finite() {
        return Vec::new();
    }
    d.iter()
        .enumerate()
        .filter(|(_, &x)| x.is_nan() || x > OUTLIER_FACTOR * spread)
        .map(|(frame, &distance)| Outlier { frame, distance, spread })
        .collect()
}

/// Camera centres closer to each other than this, relative to their coordinates' magnitude (at least 1), count as
/// one point: f32 poses resolve about 1e-7 of it, so only copies of one pose (or its rounding) fall below.
pub const COINCIDENT_RELATIVE: f64 = 1e-9;

/// Where two or more frames all have one camera centre: the largest distance of any centre from the first one and
/// the largest coordinate magnitude. Normalisation divides by that distance, so the scene's scale is undefined.
pub fn coincident_centres<'a>(frames: impl IntoIterator<Item = &'a Frame>) -> Option<(f64, f64)> {
    let mut centres = frames.into_iter().map(|f| [f.c2w[0][3], f.c2w[1][3], f.c2w[2][3]]);
    let first = centres.next()?;
    let (mut n, mut reach, mut magnitude) = (1, 0.0f64, first.iter().fold(1.0f64, |m, v| m.max(v.abs())));
    for c in centres {
        n += 1;
        reach = reach.max((c[0] - first[0]).hypot(c[1] - first[1]).hypot(c[2] - first[2]));
        magnitude = c.iter().fold(magnitude, |m, v| m.max(v.abs()));
    }
    (n >= 2 && reach <= COINCIDENT_RELATIVE * magnitude).then_some((reach, magnitude))
}
