//! The DSM's cross-check of the photometric refinement ([`super::refine`]): a second plane sweep along the same
//! vertical, with another view as the reference, as stereo's left-right consistency check matches from both images.
//!
//! A sweep's best score lies where the patches agree best, which on a uniform surface is often a wrong height with a
//! high NCC (what little signal the patches share lies at no one height). A second reference a baseline away from
//! the first sees that signal from elsewhere, and its best score lands at another height; on a textured surface
//! both land on it. A cell is measured only when both sweeps are supported, their peaks lie within `tolerance`
//! reference footprints of each other, and the cell's height is at the first peak (a supported cell that keeps the
//! field's height because its best NCC is below `move_ncc` is measured only where that peak is at the field's
//! height).
//!
//! Pure functions: the choice of the second reference and the verdict; `survey` runs the sweeps.

use super::refine_points::{PointResult, RefinePoint};

/// The second reference stands at least this fraction of the first reference's distance to the cell from it.
pub const MIN_BASELINE_RATIO: f64 = 0.2;

/// The cross-check's sweep for `first` (its reference `first.frame`, its partners the other agreeing views), started
/// from `p0` (where the first sweep started; `first.p` may have moved since): the most nadir partner (largest
/// `nadir`) that `holds` the whole sweep and whose centre (`centres`, by frame) stands at least
/// [`MIN_BASELINE_RATIO`] of the first reference's distance from it; the first reference becomes a partner. None when
/// no partner qualifies.
pub fn second_reference(
    first: &RefinePoint,
    p0: [f64; 3],
    centres: &[[f64; 3]],
    holds: impl Fn(u32) -> bool,
    nadir: impl Fn(u32) -> f64,
) -> Option<RefinePoint> {
    let c0 = glam::DVec3::from(centres[first.frame]);
    let reach = (glam::DVec3::from(p0) - c0).length() * MIN_BASELINE_RATIO;
    let pick = (first.partners.iter().enumerate())
        .filter(|(_, &f)| (glam::DVec3::from(centres[f as usize]) - c0).length() >= reach)
        .filter(|(_, &f)| holds(f))
        .max_by(|a, b| nadir(*a.1).total_cmp(&nadir(*b.1)))
        .map(|(i, _)| i)?;
    let mut partners = first.partners.clone();
    let frame = partners.swap_remove(pick) as usize;
    partners.push(first.frame as u32);
    Some(RefinePoint { p: p0, dir: first.dir, frame, partners })
}

/// Whether the second sweep confirms the first (see the module): both supported, peaks within `tolerance` of the
/// first reference's footprints, and the cell's height at the first peak. A supported cell without a second sweep
/// (`second` None) is not confirmed.
pub fn confirmed(first: &PointResult, second: Option<&PointResult>, tolerance: f64) -> bool {
    let Some(second) = second else { return false };
    let near = |s: f64| s.abs() <= tolerance * first.footprint;
    first.supported && second.supported && near(first.peak - second.peak) && (first.moved || near(first.peak))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(supported: bool, moved: bool, peak: f64) -> PointResult {
        PointResult { shift: if moved { peak } else { 0.0 }, ncc: 0.9, moved, supported, peak, footprint: 0.01 }
    }

    #[test]
    fn the_verdict_needs_two_supported_sweeps_at_one_height() {
        let a = result(true, true, 0.05);
        assert!(confirmed(&a, Some(&result(true, true, 0.055)), 1.0));
        assert!(confirmed(&a, Some(&result(true, false, 0.059)), 1.0), "the second need not have moved");
        assert!(!confirmed(&a, Some(&result(true, true, 0.065)), 1.0), "1.5 footprints apart");
        assert!(confirmed(&a, Some(&result(true, true, 0.065)), 2.0));
        assert!(!confirmed(&a, Some(&result(false, false, f64::NAN)), 1.0), "second unsupported");
        assert!(!confirmed(&a, None, 1.0), "no second reference");
        assert!(!confirmed(&result(false, false, f64::NAN), Some(&a), 1.0), "first unsupported");
        // A cell kept at the field's height (peak below the move threshold) is measured only where its peak is.
        assert!(confirmed(&result(true, false, 0.004), Some(&result(true, false, 0.0)), 1.0));
        assert!(!confirmed(&result(true, false, 0.05), Some(&result(true, false, 0.05)), 1.0));
    }

    #[test]
    fn the_second_reference_is_the_most_nadir_partner_a_baseline_away() {
        // The cell 40 m below the first reference (frame 0); partners 1 (2 m away, too close), 2 (10 m), 3 (12 m,
        // more nadir than 2), 4 (20 m, more nadir still, but its image does not hold the sweep).
        let centres = [[0.0, 0.0, 40.0], [2.0, 0.0, 40.0], [10.0, 0.0, 40.0], [-12.0, 0.0, 40.0], [20.0, 0.0, 40.0]];
        let first = RefinePoint { p: [0.0, 0.0, 0.0], dir: [0.0, 0.0, -1.0], frame: 0, partners: vec![1, 2, 3, 4] };
        let nadir = |f: u32| [1.0, 0.99, 0.9, 0.95, 0.97][f as usize];
        let s = second_reference(&first, first.p, &centres, |f| f != 4, nadir).expect("a second reference");
        assert_eq!(s.frame, 3);
        let mut partners = s.partners.clone();
        partners.sort_unstable();
        assert_eq!(partners, vec![0, 1, 2, 4], "the first reference becomes a partner");
        assert_eq!((s.p, s.dir), (first.p, first.dir));
        assert!(second_reference(&first, first.p, &centres, |f| f == 1, nadir).is_none(), "only a partner too close");
    }
}
