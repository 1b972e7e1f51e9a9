//! Least-squares similarity transform between matched point sets, `dst ~ s R src + t` (Umeyama 1991's objective),
//! solved with Horn 1987's quaternion method: the rotation is the eigenvector of the largest eigenvalue of a
//! symmetric 4x4 matrix built from the cross-covariance (cyclic Jacobi here: glam has no eigen solver, and a 4x4
//! does not justify a linear-algebra crate), then the scale `s = sum(d' . R s') / sum(|s'|^2)` and
//! `t = mean(dst) - s R mean(src)`. Used to geo-register SfM models to GPS (`crate::sfm::georef`).

/// `p -> s R p + t` (R row-major).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

impl Similarity {
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        std::array::from_fn(|i| self.scale * (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2]) + self.translation[i])
    }

    /// A direction rotated (no scale, no translation).
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
    }
}

/// Eigenvalues and eigenvectors (columns of the returned matrix) of a symmetric 4x4 matrix by cyclic Jacobi.
fn jacobi4(mut a: [[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (rp, rq) = (a[p], a[q]);
                for k in 0..4 {
                    a[p][k] = c * rp[k] - s * rq[k];
                    a[q][k] = s * rp[k] + c * rq[k];
                }
                for row in v.iter_mut() {
                    let (vkp, vkq) = (row[p], row[q]);
                    row[p] = c * vkp - s * vkq;
                    row[q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2], a[3][3]], v)
}

/// The similarity that best maps `src` onto `dst` (at least 3 pairs, not all on a line); None otherwise.
pub fn fit_similarity(src: &[[f64; 3]], dst: &[[f64; 3]]) -> Option<Similarity> {
    fit_similarity_weighted(src, dst, &vec![1.0; src.len()])
}

/// [`fit_similarity`] minimising `sum w_i |s(src_i) - dst_i|^2` (Horn's closed form with weighted centroids and
/// cross-covariance; weights positive and finite).
pub fn fit_similarity_weighted(src: &[[f64; 3]], dst: &[[f64; 3]], weights: &[f64]) -> Option<Similarity> {
    let n = src.len();
    if n < 3 || dst.len() != n || weights.len() != n || weights.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return None;
    }
    let wsum: f64 = weights.iter().sum();
    let mean = |p: &[[f64; 3]]| -> [f64; 3] {
        std::array::from_fn(|k| p.iter().zip(weights).map(|(x, wi)| wi * x[k]).sum::<f64>() / wsum)
    };
    let (ms, md) = (mean(src), mean(dst));
    let mut m = [[0.0; 3]; 3]; // sum of w s' d'^T
    let mut ss = 0.0;
    for ((s, d), wi) in src.iter().zip(dst).zip(weights) {
        let a: [f64; 3] = std::array::from_fn(|k| s[k] - ms[k]);
        let b: [f64; 3] = std::array::from_fn(|k| d[k] - md[k]);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += wi * a[i] * b[j];
            }
        }
        ss += wi * a.iter().map(|x| x * x).sum::<f64>();
    }
    if ss.is_nan() || ss <= 0.0 {
        return None;
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = m;
    let nmat = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let (vals, vecs) = jacobi4(nmat);
    let mut order = [0, 1, 2, 3];
    order.sort_by(|&i, &j| vals[j].total_cmp(&vals[i]));
    // Degenerate (collinear) input: the two largest eigenvalues coincide and the rotation about the line is free.
    if (vals[order[0]] - vals[order[1]]).abs() <= 1e-9 * vals[order[0]].abs().max(1e-300) {
        return None;
    }
    let k = order[0];
    let (w, x, y, z) = (vecs[0][k], vecs[1][k], vecs[2][k], vecs[3][k]);
    let r = [
        [w * w + x * x - y * y - z * z, 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), w * w - x * x + y * y - z * z, 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ];
    let mut num = 0.0;
    for ((s, d), wi) in src.iter().zip(dst).zip(weights) {
        let a: [f64; 3] = std::array::from_fn(|k| s[k] - ms[k]);
        let ra: [f64; 3] = std::array::from_fn(|i| r[i][0] * a[0] + r[i][1] * a[1] + r[i][2] * a[2]);
        num += wi * (0..3).map(|k| (d[k] - md[k]) * ra[k]).sum::<f64>();
    }
    let scale = num / ss;
    if !scale.is_finite() || scale <= 0.0 {
        return None;
    }
    let rm: [f64; 3] = std::array::from_fn(|i| r[i][0] * ms[0] + r[i][1] * ms[1] + r[i][2] * ms[2]);
    let translation = std::array::from_fn(|i| md[i] - scale * rm[i]);
    Some(Similarity { scale, rotation: r, translation })
}
