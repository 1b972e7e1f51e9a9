//! Seed noise, measured: cells whose settings differ only in `trainer.seed` are repeats of one configuration, and
//! the spread of their held-out PSNR at each evaluation point is how far apart two runs of the same thing land.
//! The report uses it as the tie threshold instead of asserting one (issue 24, item 6). A grid measures it by
//! repeating a cell with other seeds, e.g. `- {trainer.seed: 1}` next to the base `- {}`.

use super::result::CellResult;

/// The seed key the repeats differ in.
pub const SEED_KEY: &str = "trainer.seed";

/// The spread of one configuration's repeats.
#[derive(Clone, Debug, PartialEq)]
pub struct SeedNoise {
    /// The repeated cells (sweep indices), the first the one without a seed override when there is one.
    pub cells: Vec<usize>,
    /// (evaluation point in seconds, max - min of the repeats' held-out PSNR in dB), for points every repeat has.
    pub spread_db: Vec<(f64, f64)>,
}

impl SeedNoise {
    /// The largest spread over the evaluation points.
    pub fn max_db(&self) -> f64 {
        self.spread_db.iter().map(|&(_, d)| d).fold(0.0, f64::max)
    }

    /// The tie threshold at evaluation point `target_s`: the spread measured there, or the largest one when the
    /// repeats were not evaluated at that point.
    pub fn at(&self, target_s: f64) -> f64 {
        self.spread_db.iter().find(|(t, _)| (t - target_s).abs() < 1e-9).map_or_else(|| self.max_db(), |&(_, d)| d)
    }
}

/// The settings of a cell other than its seed.
fn without_seed(r: &CellResult) -> Vec<(String, String)> {
    r.values.iter().filter(|(k, _)| k != SEED_KEY).cloned().collect()
}

/// The largest group of cells that differ only in `trainer.seed` (at least two, at least one with a seed override),
/// and its spread; None when the sweep repeats nothing.
pub fn seed_noise(results: &[CellResult]) -> Option<SeedNoise> {
    let mut best: Option<Vec<usize>> = None;
    for (i, r) in results.iter().enumerate() {
        let key = without_seed(r);
        let group: Vec<usize> = (0..results.len()).filter(|&j| without_seed(&results[j]) == key).collect();
        let seeded = group.iter().any(|&j| results[j].values.iter().any(|(k, _)| k == SEED_KEY));
        if group.len() < 2 || !seeded || group[0] != i {
            continue;
        }
        if best.as_ref().is_none_or(|b| group.len() > b.len()) {
            best = Some(group);
        }
    }
    let cells = best?;
    let targets: Vec<f64> = results[cells[0]].points.iter().map(|p| p.target_s).collect();
    let spread_db = targets
        .into_iter()
        .filter_map(|t| {
            let psnr: Vec<f64> = cells
                .iter()
                .map(|&c| results[c].points.iter().find(|p| (p.target_s - t).abs() < 1e-9).map(|p| p.psnr))
                .collect::<Option<Vec<f64>>>()?;
            if psnr.iter().any(|p| !p.is_finite()) {
                return None;
            }
            let (lo, hi) = psnr.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &p| (l.min(p), h.max(p)));
            Some((t, hi - lo))
        })
        .collect();
    Some(SeedNoise { cells: cells.iter().map(|&c| results[c].index).collect(), spread_db })
}
