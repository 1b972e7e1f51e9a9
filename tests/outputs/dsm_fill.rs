//! The DSM's gap filling (`output::raster::fill`, `nerf::survey_products::finish_dsm`):
//!
//! - inverse distance weighting along eight directions, against an independent implementation written here from
//!   the definition (for every cell to fill: the nearest source along each compass ray within the distance, weights
//!   1 / d^2, at least two directions, no two sources steeper apart than the slope limit), on a random mask;
//! - a flat, textureless pond between level banks comes out exactly at the banks' height; a gap wider than the
//!   distance limit stays a hole; a cell with sources on one side only is not extrapolated; the gap between a
//!   roof and the ground is not bridged;
//! - the four `--fill` modes on a synthetic DSM: what each code becomes, and the counts; `auto` interpolates a field
//!   height within its tolerance of the interpolation and keeps one that stands out (a crown); it interpolates a gap
//!   unless the interpolation lies above the height the gap was turned down with (a step down), which stays a hole.

use msnerf::nerf::survey::{quality, DsmFill, SurveyStats};
use msnerf::nerf::survey_products::{finish_dsm, FillParams};

fn params(mode: DsmFill) -> FillParams {
    FillParams { mode, max_cells: 100.0, max_rise_per_cell: 1000.0, tolerance: 1.0 }
}
use msnerf::output::raster::fill::fill_idw;

/// The definition, cell by cell, in f64.
#[allow(clippy::too_many_arguments)]
fn reference(
    values: &[f32],
    source: &[bool],
    w: usize,
    h: usize,
    r: usize,
    c: usize,
    max: f64,
    rise: f64,
) -> Option<f64> {
    // (distance, value, row, col) of the nearest source along each direction.
    let mut found: Vec<(f64, f64, f64, f64)> = Vec::new();
    for (dr, dc) in [(-1i64, -1i64), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)] {
        for k in 1.. {
            let (rr, cc) = (r as i64 + dr * k, c as i64 + dc * k);
            let d = (((dr * k) * (dr * k) + (dc * k) * (dc * k)) as f64).sqrt();
            if d > max + 1e-9 || rr < 0 || cc < 0 || rr >= h as i64 || cc >= w as i64 {
                break;
            }
            let j = rr as usize * w + cc as usize;
            if source[j] {
                found.push((d, values[j] as f64, rr as f64, cc as f64));
                break;
            }
        }
    }
    if found.len() < 2 {
        return None;
    }
    for a in &found {
        for b in &found {
            if (a.1 - b.1).abs() > rise * (a.2 - b.2).hypot(a.3 - b.3) {
                return None;
            }
        }
    }
    let (sw, swv) = found.iter().fold((0.0, 0.0), |(a, b), (d, v, _, _)| (a + 1.0 / (d * d), b + v / (d * d)));
    Some(swv / sw)
}

#[test]
fn idw_fill_matches_its_definition() {
    let (w, h) = (37, 23);
    use rand::Rng;
    let mut r = crate::common::rng(12345);
    let mut rnd = || r.random::<f64>();
    let values: Vec<f32> = (0..w * h).map(|_| (100.0 + 10.0 * rnd()) as f32).collect();
    let source: Vec<bool> = (0..w * h).map(|_| rnd() < 0.15).collect();
    let fill: Vec<bool> = source.iter().map(|s| !s).collect();
    for (max, rise) in [(3.0, 100.0), (7.5, 100.0), (100.0, 100.0), (100.0, 1.0), (7.5, 3.0)] {
        let got = fill_idw(&values, &source, &fill, w, h, max, rise);
        let mut filled = 0;
        for r in 0..h {
            for c in 0..w {
                let i = r * w + c;
                if source[i] {
                    assert_eq!(got[i], None, "a source cell is not asked for");
                    continue;
                }
                let want = reference(&values, &source, w, h, r, c, max, rise);
                match (got[i], want) {
                    (Some(g), Some(v)) => {
                        assert!((g as f64 - v).abs() < 1e-4, "({r}, {c}) max {max}: {g} vs {v}");
                        filled += 1;
                    }
                    (None, None) => {}
                    other => panic!("({r}, {c}) max {max}: {other:?}"),
                }
            }
        }
        assert!(filled > 0, "max {max}, rise {rise}: nothing filled");
    }
}

#[test]
fn a_pond_comes_out_flat_at_its_banks_and_a_wide_gap_stays_a_hole() {
    // 40 x 20 cells: banks at 12.5 m all round a 16 x 10 pond; a 30-cell-wide gap elsewhere on a row.
    let (w, h) = (40, 20);
    let mut values = vec![12.5f32; w * h];
    let mut source = vec![true; w * h];
    for r in 5..15 {
        for c in 4..20 {
            source[r * w + c] = false;
            values[r * w + c] = f32::NAN;
        }
    }
    let fill: Vec<bool> = source.iter().map(|s| !s).collect();
    let got = fill_idw(&values, &source, &fill, w, h, 100.0, 1.0);
    for r in 5..15 {
        for c in 4..20 {
            assert_eq!(got[r * w + c], Some(12.5), "({r}, {c})");
        }
    }
    // Within 4 cells only: the pond's middle (5 or more cells from every bank) stays a hole.
    let near = fill_idw(&values, &source, &fill, w, h, 4.0, 1.0);
    assert!(near[10 * w + 12].is_none() && near[5 * w + 4].is_some());
    // A single source: every cell finds it in one direction at most, so nothing is extrapolated from it.
    let mut src = vec![false; w * h];
    src[0] = true;
    let one = fill_idw(&values, &src, &vec![true; w * h], w, h, 100.0, 1.0);
    assert!(one.iter().all(|v| v.is_none()), "one source, one direction: nothing extrapolated");
    // A roof at 27 m beside ground at 20 m with a 3-cell gap between (a wall the filters dropped): a step of 7 m
    // over 4 cells of 0.4 m is far steeper than 45 degrees, so the gap stays a hole; at 1 m it would be bridged.
    let (w, h) = (12, 1);
    let v: Vec<f32> = (0..w).map(|c| if c < 4 { 27.0 } else { 20.0 }).collect();
    let src: Vec<bool> = (0..w).map(|c| !(4..7).contains(&c)).collect();
    let want: Vec<bool> = src.iter().map(|s| !s).collect();
    assert!(fill_idw(&v, &src, &want, w, h, 100.0, 0.4).iter().all(|x| x.is_none()));
    assert!(fill_idw(&v, &src, &want, w, h, 100.0, 2.0).iter().filter(|x| x.is_some()).count() == 3);
}

#[test]
fn the_fill_modes_decide_what_unsupported_cells_become() {
    use quality::{FIELD_ONLY, GAP, MEASURED, NODATA};
    // A row: measured 10 | field-only 99 | gap | measured 20 | nodata (no surface).
    let (w, h) = (5, 1);
    let z0 = vec![10.0f32, 99.0, f32::NAN, 20.0, f32::NAN];
    let q0 = vec![MEASURED, FIELD_ONLY, GAP, MEASURED, NODATA];
    let run = |fill: DsmFill, refined: bool| {
        let (mut z, mut q) = (z0.clone(), q0.clone());
        if !refined {
            // Without the refinement no cell is measured: every height is the field's.
            q.iter_mut().filter(|c| **c == MEASURED).for_each(|c| *c = FIELD_ONLY);
        }
        let mut st = SurveyStats { cells: w * h, ..Default::default() };
        finish_dsm(&mut z, &mut q, w, h, &params(fill), refined, &mut st);
        (z, q, st)
    };
    let (z, q, st) = run(DsmFill::Interpolate, true);
    assert_eq!(q, vec![MEASURED, quality::INTERPOLATED, quality::INTERPOLATED, MEASURED, NODATA]);
    // IDW between 10 (1 cell left) and 20 (2 cells right): (10/1 + 20/4) / (1 + 1/4) = 12.
    assert!((z[1] - 12.0).abs() < 1e-5 && (z[2] - (10.0 / 4.0 + 20.0) / 1.25).abs() < 1e-5, "{z:?}");
    assert!(z[4].is_nan());
    assert_eq!((st.measured, st.interpolated, st.field_only, st.valid), (2, 2, 0, 4));
    let (z, q, st) = run(DsmFill::Field, true);
    assert_eq!(q, vec![MEASURED, FIELD_ONLY, NODATA, MEASURED, NODATA]);
    assert_eq!(z[1], 99.0);
    assert!(z[2].is_nan());
    assert_eq!((st.measured, st.field_only, st.valid), (2, 1, 3));
    let (z, q, st) = run(DsmFill::None, true);
    assert_eq!(q, vec![MEASURED, NODATA, NODATA, MEASURED, NODATA]);
    assert!(z[1].is_nan() && z[2].is_nan());
    assert_eq!(st.valid, 2);
    // Without the refinement the field's consistent heights are what there is: kept, and the gap filled from them.
    let (z, q, st) = run(DsmFill::Interpolate, false);
    assert_eq!(q, vec![FIELD_ONLY, FIELD_ONLY, quality::INTERPOLATED, FIELD_ONLY, NODATA]);
    assert_eq!(z[1], 99.0);
    assert!((z[2] - (99.0 + 20.0) / 2.0).abs() < 1e-4, "{z:?}");
    assert_eq!((st.measured, st.field_only, st.interpolated), (0, 3, 1));
    // Auto: the field-only cell at 99 stands 87 above its interpolation (12) and is kept; the gap, turned down at
    // a field height of 18.4 (its interpolation: 18), is interpolated; at 16.5 (the interpolation 1.5 above it) or
    // without a height, it stays a hole.
    let auto = |gap_z: f32| {
        let (mut z, mut q) = (z0.clone(), q0.clone());
        z[2] = gap_z;
        let mut st = SurveyStats { cells: w * h, ..Default::default() };
        finish_dsm(&mut z, &mut q, w, h, &params(DsmFill::Auto), true, &mut st);
        (z, q, st)
    };
    let (z, q, st) = auto(18.4);
    assert_eq!(q, vec![MEASURED, FIELD_ONLY, quality::INTERPOLATED, MEASURED, NODATA]);
    assert_eq!(z[1], 99.0);
    assert!((z[2] - (10.0 / 4.0 + 20.0) / 1.25).abs() < 1e-5, "{z:?}");
    assert_eq!((st.measured, st.interpolated, st.field_only, st.valid), (2, 1, 1, 4));
    // Turned down at 25, above its interpolation (a floater): interpolated too.
    let (z, q, _) = auto(25.0);
    assert!(q[2] == quality::INTERPOLATED && (z[2] - 18.0).abs() < 1e-5, "{q:?} {z:?}");
    for gap_z in [16.5, f32::NAN] {
        let (z, q, st) = auto(gap_z);
        assert_eq!(q, vec![MEASURED, FIELD_ONLY, NODATA, MEASURED, NODATA], "gap at {gap_z}");
        assert!(z[2].is_nan() && st.interpolated == 0, "gap at {gap_z}: {z:?}");
    }
}

/// `auto` on a lawn with a tree: measured lawn at 0 m round a square of unsupported cells, the field's height
/// within the tolerance on the lawn's part (0.4-0.9 m: the field's error) and a crown 8 m high in the middle. The
/// lawn's cells come out at the interpolated 0 m, the crown keeps the field's height.
#[test]
fn auto_fills_a_lawn_and_keeps_a_crown() {
    use quality::{FIELD_ONLY, INTERPOLATED, MEASURED};
    let (w, h) = (21, 21);
    let mut z = vec![0.0f32; w * h];
    let mut q = vec![MEASURED; w * h];
    for r in 3..18 {
        for c in 3..18 {
            let i = r * w + c;
            q[i] = FIELD_ONLY;
            let crown = (r as i32 - 10).abs() <= 2 && (c as i32 - 10).abs() <= 2;
            z[i] = if crown { 8.0 } else { 0.4 + 0.5 * ((r + c) % 2) as f32 };
        }
    }
    let before = z.clone();
    let mut st = SurveyStats { cells: w * h, ..Default::default() };
    finish_dsm(&mut z, &mut q, w, h, &params(DsmFill::Auto), true, &mut st);
    for r in 3..18 {
        for c in 3..18 {
            let i = r * w + c;
            if before[i] == 8.0 {
                assert_eq!((q[i], z[i]), (FIELD_ONLY, 8.0), "crown cell ({r}, {c})");
            } else {
                assert_eq!(q[i], INTERPOLATED, "lawn cell ({r}, {c})");
                assert!(z[i].abs() < 1e-6, "lawn cell ({r}, {c}) at {}", z[i]);
            }
        }
    }
    assert_eq!((st.field_only, st.interpolated), (25, 15 * 15 - 25));
}
