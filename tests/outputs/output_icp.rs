//! Trimmed ICP with a similarity (`output::pointcloud::icp`): a terrain with relief (ridges, crowns, a hip roof) in
//! UTM-sized coordinates, sampled twice on different grids; one sampling moved by a known similarity (a 0.5 degree
//! tilt, a 0.3 degree turn, a scale of 1.002, decimetres of shift) and given 1 cm of noise and 10 % of outliers.
//! ICP from the identity must find the known transform: the points back within 5 mm RMS (1 cm at worst), the tilt
//! within 0.01 degrees, the scale within 2e-4.

use msnerf::maths::similarity::Similarity;
use msnerf::output::pointcloud::icp::{icp_similarity, identity, rotation_angles, IcpOptions};
use msnerf::output::pointcloud::kdtree::KdTree;

const ORIGIN: [f64; 3] = [307_000.0, 5_341_000.0, 330.0];

fn height(x: f64, y: f64) -> f64 {
    let ridges = 0.8 * (x / 7.0).sin() + 0.5 * (y / 5.0).cos();
    // Crowns and a hip-roofed barn: smooth, so every sample has a tangent plane (a vertical wall, which a sampled
    // terrain does not hold, would bend the normals of its edge).
    let crown = |cx: f64, cy: f64, r: f64, h: f64| h * (-((x - cx).powi(2) + (y - cy).powi(2)) / (r * r)).exp();
    let barn = (6.0 - 0.8 * ((x - 28.0).abs().max((y - 25.0).abs() * 1.5))).max(0.0);
    ridges + crown(10.0, 12.0, 3.0, 6.0) + crown(15.0, 30.0, 2.5, 5.0) + barn
}

fn terrain(step: f64, offset: f64) -> Vec<[f64; 3]> {
    let n = (40.0 / step) as usize;
    let mut v = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 * step + offset, j as f64 * step + offset);
            v.push([ORIGIN[0] + x, ORIGIN[1] + y, ORIGIN[2] + height(x, y)]);
        }
    }
    v
}

/// Rotation about a unit axis (Rodrigues), row-major.
fn rot(axis: [f64; 3], deg: f64) -> [[f64; 3]; 3] {
    let (s, c) = deg.to_radians().sin_cos();
    let [x, y, z] = axis;
    [
        [c + x * x * (1.0 - c), x * y * (1.0 - c) - z * s, x * z * (1.0 - c) + y * s],
        [y * x * (1.0 - c) + z * s, c + y * y * (1.0 - c), y * z * (1.0 - c) - x * s],
        [z * x * (1.0 - c) - y * s, z * y * (1.0 - c) + x * s, c + z * z * (1.0 - c)],
    ]
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// The known transform, taking the moved cloud back onto the terrain: about the terrain's centre.
fn known(scale: f64) -> Similarity {
    let r = mul(rot([0.0, 0.0, 1.0], 0.3), rot([0.6, 0.8, 0.0], 0.5));
    let centre = [ORIGIN[0] + 20.0, ORIGIN[1] + 20.0, ORIGIN[2]];
    let shift = [0.3, -0.2, 0.15];
    // p -> s R (p - centre) + centre + shift
    let rc: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| r[i][k] * centre[k]).sum());
    Similarity { scale, rotation: r, translation: std::array::from_fn(|i| centre[i] + shift[i] - scale * rc[i]) }
}

fn inverse_apply(s: &Similarity, q: [f64; 3]) -> [f64; 3] {
    let d: [f64; 3] = std::array::from_fn(|i| q[i] - s.translation[i]);
    std::array::from_fn(|i| (0..3).map(|k| s.rotation[k][i] * d[k]).sum::<f64>() / s.scale)
}

/// A deterministic hash noise in [-1, 1].
fn noise(i: usize, k: usize) -> f64 {
    let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (k as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 31;
    h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^= h >> 29;
    (h % 2_000_001) as f64 / 1_000_000.0 - 1.0
}

/// The other sampling, away from the border (so every point has terrain under it after the move).
fn inner_sampling() -> Vec<[f64; 3]> {
    terrain(0.37, 0.05)
        .into_iter()
        .filter(|p| (p[0] - ORIGIN[0] - 20.0).abs() < 17.0 && (p[1] - ORIGIN[1] - 20.0).abs() < 17.0)
        .collect()
}

#[test]
fn icp_recovers_a_known_similarity_on_terrain_with_relief_and_outliers() {
    let target = terrain(0.1, 0.0);
    let tree = KdTree::new(&target);
    let truth = known(1.002);
    let on_surface = inner_sampling();
    let source: Vec<[f64; 3]> = on_surface
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let mut q = p;
            q[2] += 0.01 * noise(i, 0);
            if i % 10 == 3 {
                q[2] += 2.0 + 3.0 * noise(i, 1); // an outlier: a bird, a wire
            }
            inverse_apply(&truth, q)
        })
        .collect();
    // The moved cloud starts visibly off the surface.
    let before = source.iter().map(|p| tree.nearest(p).unwrap().1.sqrt()).fold(0.0, f64::max);
    assert!(before > 0.2, "{before}");

    let o = IcpOptions { scale: true, ..IcpOptions::default() };
    let r = icp_similarity(&source, &target, &tree, identity(), &o).expect("icp");
    let mut worst: f64 = 0.0;
    let (mut sq, mut n) = (0.0, 0usize);
    for (i, &p) in source.iter().enumerate() {
        if i % 10 == 3 {
            continue;
        }
        let (a, b) = (r.similarity.apply(p), truth.apply(p));
        let e = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
        worst = worst.max(e.sqrt());
        sq += e;
        n += 1;
    }
    let rms_err = (sq / n as f64).sqrt();
    let (_, tilt) = rotation_angles(&r.similarity);
    let (_, true_tilt) = rotation_angles(&truth);
    eprintln!(
        "ICP: {} iterations, rms {:.4} m, points {:.4} m RMS ({:.4} m at worst) off the known transform, tilt {:.4} \
         (true {:.4}) deg, scale {:.5}",
        r.iterations, r.rms, rms_err, worst, tilt, true_tilt, r.similarity.scale
    );
    assert!(rms_err < 0.005, "the points land {rms_err} m RMS from where the known transform puts them");
    assert!(worst < 0.01, "a point lands {worst} m from where the known transform puts it");
    assert!((tilt - true_tilt).abs() < 0.01, "tilt {tilt} vs {true_tilt}");
    assert!((r.similarity.scale - truth.scale).abs() < 2e-4, "{} vs {}", r.similarity.scale, truth.scale);
}

/// Rigid (the default): the same terrain turned and shifted without a scale comes back; the scale stays 1.
#[test]
fn rigid_icp_recovers_a_turn_and_a_shift() {
    let target = terrain(0.1, 0.0);
    let tree = KdTree::new(&target);
    let truth = known(1.0);
    let source: Vec<[f64; 3]> = inner_sampling().into_iter().map(|p| inverse_apply(&truth, p)).collect();
    let r = icp_similarity(&source, &target, &tree, identity(), &IcpOptions::default()).expect("icp");
    assert_eq!(r.similarity.scale, 1.0);
    let worst = source
        .iter()
        .map(|&p| {
            let (a, b) = (r.similarity.apply(p), truth.apply(p));
            (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
        })
        .fold(0.0, f64::max);
    assert!(worst < 0.01, "{worst}");
}

#[test]
fn icp_needs_seven_points() {
    let target = terrain(1.0, 0.0);
    let tree = KdTree::new(&target);
    let r = icp_similarity(&[[ORIGIN[0], ORIGIN[1], ORIGIN[2]]; 6], &target, &tree, identity(), &IcpOptions::default());
    assert!(r.is_none());
}
