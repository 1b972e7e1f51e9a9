//! Trimmed point-to-plane iterative closest point with a similarity: the 7-parameter transform that best lays one
//! cloud on another's surface, as CloudCompare's "fine registration" does before a relative accuracy is read.
//!
//! Point-to-plane (Chen & Medioni 1992) rather than point-to-point (Besl & McKay 1992): on terrain, most of the
//! surface is near-horizontal and point-to-point pairs slide along it for hundreds of iterations. Each iteration
//! pairs every moved source point with its nearest target point ([`KdTree`]), whose normal is the local plane of its
//! `NORMAL_NEIGHBOURS` nearest targets ([`fit_plane`]), keeps the `keep` fraction of pairs closest to
//! their planes (trimmed ICP, Chetverikov et al. 2002), and solves the linearised step (small rotation `w`,
//! translation `t`, scale change `d` about the kept points' centroid `c`: residual `n . (m - q) + (p x n) . w +
//! n . t + d (n . p)` with `p = m - c`) by least squares; the step is applied as an exact rotation. It stops when
//! the step moves no source point by more than `tolerance`, or after `iterations`. Directions no pair constrains
//! (a flat plane's in-plane shift) are left where they are by a small damping.
//!
//! The scale is free only on request (`scale: true`): point-to-plane residuals do not see a cloud shrink along a
//! surface, and with trimming a partial overlap can shrink towards one patch of the target. Rigid (the default) is
//! what a relative accuracy needs where the scale error is small against the figures read.

use glam::{DMat3, DVec3};

use super::kdtree::KdTree;
use super::local_plane::fit_plane;
use crate::maths::similarity::Similarity;

/// Target points whose plane gives a target point's normal.
const NORMAL_NEIGHBOURS: usize = 10;

/// Options of [`icp_similarity`].
#[derive(Debug, Clone, Copy)]
pub struct IcpOptions {
    pub iterations: usize,
    /// Fraction of the pairs closest to their planes refitted each iteration (0, 1].
    pub keep: f64,
    /// Stop when no source point moves more than this in one step (world units).
    pub tolerance: f64,
    /// Fit a scale too (a similarity); otherwise a rigid transform (see the module doc).
    pub scale: bool,
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions { iterations: 100, keep: 0.8, tolerance: 1e-5, scale: false }
    }
}

/// The result: the transform (source to target), the iterations run, and the RMS point-to-plane distance of the
/// kept pairs at the last iteration.
#[derive(Debug, Clone, Copy)]
pub struct IcpResult {
    pub similarity: Similarity,
    pub iterations: usize,
    pub rms: f64,
}

/// The identity similarity.
pub fn identity() -> Similarity {
    Similarity { scale: 1.0, rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] }
}

/// Lays `source` on the surface sampled by `target` (whose tree is `tree`) starting from `init`; None when fewer
/// than 7 pairs have a plane or the step cannot be solved.
pub fn icp_similarity(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    tree: &KdTree,
    init: Similarity,
    o: &IcpOptions,
) -> Option<IcpResult> {
    let mut normals: Vec<Option<Option<DVec3>>> = vec![None; target.len()];
    let mut normal = |j: usize| -> Option<DVec3> {
        *normals[j].get_or_insert_with(|| {
            let pts: Vec<DVec3> =
                tree.knn(&target[j], NORMAL_NEIGHBOURS).iter().map(|&(i, _)| DVec3::from(target[i])).collect();
            fit_plane(&pts).map(|(_, n)| n)
        })
    };
    let mut sim = init;
    let mut rms = f64::NAN;
    for it in 1..=o.iterations.max(1) {
        let moved: Vec<DVec3> = source.iter().map(|&p| DVec3::from(sim.apply(p))).collect();
        // (signed distance to the plane, moved point, normal)
        let mut pairs: Vec<(f64, DVec3, DVec3)> = moved
            .iter()
            .filter_map(|m| {
                let (j, _) = tree.nearest(&m.to_array())?;
                let n = normal(j)?;
                Some((n.dot(*m - DVec3::from(target[j])), *m, n))
            })
            .collect();
        pairs.sort_by(|a, b| a.0.abs().total_cmp(&b.0.abs()));
        pairs.truncate((pairs.len() as f64 * o.keep.clamp(0.0, 1.0)).ceil() as usize);
        if pairs.len() < 7 {
            return None;
        }
        rms = (pairs.iter().map(|p| p.0 * p.0).sum::<f64>() / pairs.len() as f64).sqrt();
        let c = pairs.iter().map(|p| p.1).sum::<DVec3>() / pairs.len() as f64;
        let mut ata = [[0.0f64; 7]; 7];
        let mut atb = [0.0f64; 7];
        for &(d, m, n) in &pairs {
            let p = m - c;
            let pn = p.cross(n);
            let row = [pn.x, pn.y, pn.z, n.x, n.y, n.z, if o.scale { n.dot(p) } else { 0.0 }];
            for a in 0..7 {
                for b in 0..7 {
                    ata[a][b] += row[a] * row[b];
                }
                atb[a] -= row[a] * d;
            }
        }
        let damping = 1e-9 * (0..7).map(|k| ata[k][k]).sum::<f64>().max(1e-300);
        if !o.scale {
            ata[6][6] = 1.0;
        }
        for (k, r) in ata.iter_mut().enumerate() {
            r[k] += damping;
        }
        let x = crate::maths::linear::solve(ata.iter().flatten().copied().collect(), atb.to_vec())?;
        let w = DVec3::new(x[0], x[1], x[2]);
        let (t, d) = (DVec3::new(x[3], x[4], x[5]), x[6]);
        let r = if w.length() > 0.0 { DMat3::from_axis_angle(w.normalize(), w.length()) } else { DMat3::IDENTITY };
        // The step U(m) = c + (1 + d) R (m - c) + t, composed after `sim`.
        let step = |m: DVec3| c + (1.0 + d) * (r * (m - c)) + t;
        let old = DMat3::from_cols_array_2d(&sim.rotation).transpose();
        let rot = r * old;
        let cols = rot.transpose().to_cols_array_2d();
        let translation = step(DVec3::from(sim.translation));
        // U(s R p + t0) = (1 + d) s (r R) p + U(t0).
        let next = Similarity { scale: (1.0 + d) * sim.scale, rotation: cols, translation: translation.to_array() };
        let moved_most = moved.iter().map(|m| (step(*m) - *m).length()).fold(0.0, f64::max);
        sim = next;
        if !moved_most.is_finite() {
            return None;
        }
        if moved_most <= o.tolerance {
            return Some(IcpResult { similarity: sim, iterations: it, rms });
        }
    }
    Some(IcpResult { similarity: sim, iterations: o.iterations.max(1), rms })
}

/// The rotation angle of a similarity (degrees) and the tilt of its z axis from vertical (degrees).
pub fn rotation_angles(s: &Similarity) -> (f64, f64) {
    let r = &s.rotation;
    let trace = r[0][0] + r[1][1] + r[2][2];
    let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
    let tilt = r[2][2].clamp(-1.0, 1.0).acos().to_degrees();
    (angle, tilt)
}
