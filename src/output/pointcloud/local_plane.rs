//! Distance from a point to a cloud's surface through a local least-squares plane (CloudCompare's cloud-to-cloud
//! distance with "local modeling: least square plane").
//!
//! The nearest-neighbour distance to a sampled surface is never zero for a point that lies on the surface between
//! samples: on the simulator's default ground truth (196,608 samples of the campus) a perfect cloud is 0.21 m
//! (median) from it, with a planar RMSE of 0.29 m, which alone almost fails a 0.3 m standard. The local model fits a
//! plane to the `k` reference points nearest the query and measures the distance to that plane, as CloudCompare,
//! PDAL's and Metashape's cloud comparisons do, so the metric measures the cloud rather than the reference's
//! sampling.
//!
//! Guards, so the model never reports less than the data supports: the plane is used only where the query's foot
//! point lies inside the neighbourhood (within the farthest neighbour's distance from their centroid; beyond a
//! hole's edge the nearest-neighbour distance stands) and only where it is closer than the nearest neighbour (a
//! plane through an edge or a crown is a poor model; the smaller distance is the honest one there, as
//! CloudCompare's documentation advises for C2C with a local model).
//!
//! The plane is the centroid and the eigenvector of the smallest eigenvalue of the neighbours' covariance
//! ([`smallest_eigenvector`], closed form for symmetric 3x3 matrices on glam's `DMat3`: glam has no eigen solver,
//! and a linear-algebra crate for one 3x3 solve would cost more build time than these lines).

use super::kdtree::KdTree;
use glam::{DMat3, DVec3};

/// A query's nearest point on the reference surface, as the offset `query - foot` and the nearest reference point
/// (for attributes such as reflectance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceOffset {
    /// Index of the nearest reference point.
    pub nearest: usize,
    /// `query - foot point` (the foot point is on the local plane, or the nearest point where the plane is not
    /// used); its length is the distance.
    pub offset: [f64; 3],
    /// Whether the local plane gave the distance.
    pub plane: bool,
}

impl Default for SurfaceOffset {
    /// No surface: an infinite offset (an empty reference).
    fn default() -> Self {
        SurfaceOffset { nearest: usize::MAX, offset: [f64::INFINITY; 3], plane: false }
    }
}

impl SurfaceOffset {
    pub fn distance(&self) -> f64 {
        DVec3::from(self.offset).length()
    }
}

/// The offset of `q` from the surface that `tree` samples (`points` are the tree's points, by index), through the
/// least-squares plane of its `k` nearest points (k >= 3), or the nearest point where the plane does not apply
/// (see the module's guards). `k` < 3 gives the nearest-neighbour offset. `None` for an empty tree.
pub fn surface_offset(tree: &KdTree, points: &[[f64; 3]], q: &[f64; 3], k: usize) -> Option<SurfaceOffset> {
    let nn = tree.knn(q, k.max(1));
    let &(nearest, nn_d2) = nn.first()?;
    let qv = DVec3::from(*q);
    let fallback = SurfaceOffset { nearest, offset: (qv - DVec3::from(points[nearest])).to_array(), plane: false };
    if k < 3 || nn.len() < 3 {
        return Some(fallback);
    }
    let nbrs: Vec<DVec3> = nn.iter().map(|&(i, _)| DVec3::from(points[i])).collect();
    let Some((c, normal)) = fit_plane(&nbrs) else { return Some(fallback) };
    let radius2 = nbrs.iter().map(|p| (*p - c).length_squared()).fold(0.0, f64::max);
    let d = qv - c;
    let h = d.dot(normal);
    let offset = normal * h;
    if (d - offset).length_squared() <= radius2 && h * h < nn_d2 {
        Some(SurfaceOffset { nearest, offset: offset.to_array(), plane: true })
    } else {
        Some(fallback)
    }
}

/// The least-squares plane of `points` (at least 3): their centroid and the unit normal, the eigenvector of the
/// smallest eigenvalue of their covariance; `None` where [`smallest_eigenvector`] finds no plane.
pub fn fit_plane(points: &[DVec3]) -> Option<(DVec3, DVec3)> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let c = points.iter().sum::<DVec3>() / n;
    let mut cov = DMat3::ZERO;
    for p in points {
        let d = *p - c;
        // Outer product d d^T, column by column.
        cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z) / n;
    }
    Some((c, smallest_eigenvector(&cov)?))
}

/// The unit eigenvector of the smallest eigenvalue of the symmetric matrix `m` (the normal of a least-squares plane
/// when `m` is a covariance). Eigenvalues by the trigonometric closed form (Smith 1961), the eigenvector as the
/// largest cross product of two rows of `m - λI`. `None` when the smallest eigenvalue is not separated from the
/// middle one (an isotropic or linear neighbourhood: no plane) or `m` is not finite.
pub fn smallest_eigenvector(m: &DMat3) -> Option<DVec3> {
    if !m.is_finite() {
        return None;
    }
    let q = (m.x_axis.x + m.y_axis.y + m.z_axis.z) / 3.0;
    let shifted = *m - DMat3::from_diagonal(DVec3::splat(q));
    // Frobenius norm / sqrt(6) of the shifted matrix (p of the closed form).
    let p =
        ([shifted.x_axis, shifted.y_axis, shifted.z_axis].iter().map(|c| c.length_squared()).sum::<f64>() / 6.0).sqrt();
    if p <= 0.0 || !p.is_finite() {
        return None;
    }
    let phi = ((shifted / p).determinant() / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos();
    let middle = 3.0 * q - largest - smallest;
    // A plane needs its normal direction to stand out: the smallest eigenvalue clearly below the middle one.
    if middle - smallest <= 1e-9 * (largest.abs() + 1e-300) {
        return None;
    }
    // m is symmetric, so its columns are its rows.
    let r = *m - DMat3::from_diagonal(DVec3::splat(smallest));
    let (a, b, c) = (r.x_axis, r.y_axis, r.z_axis);
    let best = [a.cross(b), a.cross(c), b.cross(c)]
        .into_iter()
        .max_by(|u, v| u.length_squared().total_cmp(&v.length_squared()))?;
    let len = best.length();
    (len > 0.0 && len.is_finite()).then(|| best / len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix from rows (the test matrices are written row by row; glam stores columns).
    fn mat(rows: [[f64; 3]; 3]) -> DMat3 {
        DMat3::from_cols_array_2d(&rows).transpose()
    }

    #[test]
    fn eigenvector_of_a_diagonal_and_a_rotated_matrix() {
        let v = smallest_eigenvector(&mat([[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]])).unwrap();
        assert!((v.y.abs() - 1.0).abs() < 1e-12, "{v:?}");
        // R diag(4, 2, 0.5) R^T with R a rotation about z by 30 degrees then about x by 40 degrees: the smallest
        // eigenvector is R's third column.
        let (a, b) = (30f64.to_radians(), 40f64.to_radians());
        let rz = [[a.cos(), -a.sin(), 0.0], [a.sin(), a.cos(), 0.0], [0.0, 0.0, 1.0]];
        let rx = [[1.0, 0.0, 0.0], [0.0, b.cos(), -b.sin()], [0.0, b.sin(), b.cos()]];
        let r: [[f64; 3]; 3] =
            std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| rx[i][k] * rz[k][j]).sum()));
        let l = [4.0, 2.0, 0.5];
        let m: [[f64; 3]; 3] =
            std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| r[i][k] * l[k] * r[j][k]).sum()));
        let v = smallest_eigenvector(&mat(m)).unwrap();
        let dot: f64 = (0..3).map(|i| v[i] * r[i][2]).sum();
        assert!((dot.abs() - 1.0).abs() < 1e-12, "{v:?} vs {:?}", [r[0][2], r[1][2], r[2][2]]);
    }

    #[test]
    fn isotropic_and_non_finite_matrices_have_no_plane() {
        assert!(smallest_eigenvector(&mat([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])).is_none());
        assert!(smallest_eigenvector(&mat([[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])).is_none());
        // A line (two equal small eigenvalues): no unique normal.
        assert!(smallest_eigenvector(&mat([[5.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])).is_none());
    }
}
