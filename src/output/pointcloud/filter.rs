//! Point cloud filters. Each returns the kept points through [`PointCloud::select`], the one place that picks
//! points by index, so band values, normals, colours and attributes stay aligned with their points.
//!
//! - [`remove_statistical_outliers`]: Open3D's `remove_statistical_outlier(nb_neighbors, std_ratio)`, exactly:
//!   each point's mean distance to its k nearest neighbours **including itself** (distance 0); mean and sample
//!   standard deviation (n − 1) over the points whose mean distance is > 0; keep points with
//!   `0 < d < mean + std_ratio·std`. As in Open3D, a point whose k neighbours all coincide with it is removed.
//!   (`ns-export pointcloud` uses k = 20, std_ratio = 10.)
//! - [`Aabb`]: axis-aligned crop, bounds inclusive.
//! - [`OrientedBox`]: nerfstudio's `OrientedBox` (centre T, rotation R, full side lengths S; a point is inside
//!   when `|Rᵀ(p − T)| < S/2` on every axis, strictly); `from_rpy` builds R = Rz(yaw)·Ry(pitch)·Rx(roll) like
//!   `ns-export --obb_rotation`.
//! - [`subsample`]: a deterministic random subset of a target size (seeded ChaCha8, partial Fisher–Yates), in
//!   the original point order.

use rand::{Rng, SeedableRng};

use super::kdtree::KdTree;
use super::PointCloud;
use crate::output::{OutputError, Result};

/// Statistical outlier removal; returns the filtered cloud and the kept indices.
pub fn remove_statistical_outliers(cloud: &PointCloud, k: usize, std_ratio: f64) -> Result<(PointCloud, Vec<usize>)> {
    if k < 1 || std_ratio.is_nan() || std_ratio <= 0.0 {
        return Err(OutputError::invalid(
            "statistical outlier removal",
            format!("needs k >= 1 and std_ratio > 0, got k = {k}, std_ratio = {std_ratio}"),
        ));
    }
    cloud.validate()?;
    let tree = KdTree::new(&cloud.positions);
    // Query in the tree's leaf order (cache-friendly), then scatter back to point order.
    let by_leaf = par_map(tree.leaf_order(), |&i| {
        let nn = tree.knn(&cloud.positions[i as usize], k);
        if nn.is_empty() {
            -1.0
        } else {
            nn.iter().map(|&(_, d2)| d2.sqrt()).sum::<f64>() / nn.len() as f64
        }
    });
    let mut avg = vec![0.0f64; cloud.len()];
    for (&i, d) in tree.leaf_order().iter().zip(by_leaf) {
        avg[i as usize] = d;
    }
    let valid = avg.iter().filter(|&&d| d >= 0.0).count();
    if valid == 0 {
        return Ok((cloud.select(&[]), Vec::new()));
    }
    let mean = avg.iter().filter(|&&d| d > 0.0).sum::<f64>() / valid as f64;
    let sq: f64 = avg.iter().filter(|&&d| d > 0.0).map(|d| (d - mean) * (d - mean)).sum();
    let std = (sq / (valid as f64 - 1.0)).sqrt();
    let threshold = mean + std_ratio * std;
    let keep: Vec<usize> = (0..avg.len()).filter(|&i| avg[i] > 0.0 && avg[i] < threshold).collect();
    Ok((cloud.select(&keep), keep))
}

/// `f` over `items` on all cores (scoped threads, chunks in order: the result does not depend on the thread count).
pub fn par_map<T: Sync, R: Send + Default + Clone>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).min(16);
    let chunk = items.len().div_ceil(threads).max(1024);
    let mut out = vec![R::default(); items.len()];
    let f = &f;
    std::thread::scope(|s| {
        for (q, o) in items.chunks(chunk).zip(out.chunks_mut(chunk)) {
            s.spawn(move || q.iter().zip(o.iter_mut()).for_each(|(x, r)| *r = f(x)));
        }
    });
    out
}

/// An axis-aligned box, bounds inclusive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    pub fn contains(&self, p: &[f64; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.min[a] && p[a] <= self.max[a])
    }
}

/// nerfstudio's oriented box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    pub center: [f64; 3],
    /// Box-to-world rotation (columns are the box axes).
    pub rotation: [[f64; 3]; 3],
    /// Full side lengths.
    pub scale: [f64; 3],
}

impl OrientedBox {
    /// From centre, roll/pitch/yaw in radians (R = Rz(yaw)·Ry(pitch)·Rx(roll)) and full side lengths.
    pub fn from_rpy(center: [f64; 3], rpy: [f64; 3], scale: [f64; 3]) -> OrientedBox {
        let (sr, cr) = rpy[0].sin_cos();
        let (sp, cp) = rpy[1].sin_cos();
        let (sy, cy) = rpy[2].sin_cos();
        let rotation = [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ];
        OrientedBox { center, rotation, scale }
    }

    pub fn contains(&self, p: &[f64; 3]) -> bool {
        let d = [p[0] - self.center[0], p[1] - self.center[1], p[2] - self.center[2]];
        (0..3).all(|j| {
            let local = self.rotation[0][j] * d[0] + self.rotation[1][j] * d[1] + self.rotation[2][j] * d[2];
            local > -self.scale[j] / 2.0 && local < self.scale[j] / 2.0
        })
    }
}

/// The points for which `inside` holds; returns the cloud and the kept indices.
pub fn crop(cloud: &PointCloud, inside: impl Fn(&[f64; 3]) -> bool) -> Result<(PointCloud, Vec<usize>)> {
    cloud.validate()?;
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| inside(&cloud.positions[i])).collect();
    Ok((cloud.select(&keep), keep))
}

/// At most `target` points chosen uniformly at random with `seed` (the same seed gives the same subset),
/// kept in their original order. A cloud no larger than `target` is returned whole.
pub fn subsample(cloud: &PointCloud, target: usize, seed: u64) -> Result<(PointCloud, Vec<usize>)> {
    cloud.validate()?;
    let n = cloud.len();
    if n <= target {
        let all: Vec<usize> = (0..n).collect();
        return Ok((cloud.clone(), all));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut idx: Vec<usize> = (0..n).collect();
    for i in 0..target {
        let j = rng.random_range(i..n);
        idx.swap(i, j);
    }
    idx.truncate(target);
    idx.sort_unstable();
    Ok((cloud.select(&idx), idx))
}
