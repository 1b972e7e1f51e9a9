//! The bundle adjustment on ground control (`msnerf::sfm::bundle`), judged against a synthetic flight's truth:
//! a 5 x 6 grid of nadir cameras 40 m over rolling ground, tie points seen with 0.3 px of noise, five control points
//! clicked with 0.5 px, GPS fixes with a datum shift and 0.5 m of noise. The adjustment starts from a model bent
//! the way a small flight's SfM bends (a twist and a bowl of a few decimetres, on the cameras and the points),
//! which a similarity cannot remove, and must bring the tie points and the cameras back to the truth, find the GPS
//! datum shift, and leave an undeformed problem where it is.

use msnerf::sfm::bundle::{adjust, project, rotation_exp, Camera, Observation, Problem};

const SHIFT: [f64; 3] = [0.6, -0.4, 0.9];
/// Image size and focal length (pixels): 0.05 m ground sampling distance from 40 m.
const W: f64 = 640.0;
const H: f64 = 480.0;
const F: f64 = 800.0;

/// A deterministic uniform value in [0, 1), reproducible across platforms.
fn uniform(i: usize, k: usize) -> f64 {
    // splitmix64 of the index, then of that mixed with the stream.
    let mix = |mut z: u64| {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    (mix(mix(i as u64) ^ k as u64) >> 11) as f64 / (1u64 << 53) as f64
}

/// A deterministic value of unit variance (the sum of twelve uniforms).
fn noise(i: usize, k: usize) -> f64 {
    (0..12).map(|m| uniform(i, k * 16 + m)).sum::<f64>() - 6.0
}

fn ground(x: f64, y: f64) -> f64 {
    1.5 * (x / 9.0).sin() * (y / 13.0).cos() + 0.02 * x
}

struct Scene {
    cameras: Vec<Camera>,
    points: Vec<[f64; 3]>,
    control: Vec<[f64; 3]>,
    checks: Vec<[f64; 3]>,
}

fn scene() -> Scene {
    let mut cameras = Vec::new();
    for i in 0..5 {
        for j in 0..6 {
            let n = cameras.len();
            // Nadir: camera z (forward) points down, x east, y south; a little roll, pitch and yaw per capture.
            let nadir = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
            let e = rotation_exp([0.02 * noise(n, 0), 0.02 * noise(n, 1), 0.05 * noise(n, 2)]);
            let r = std::array::from_fn(|a| std::array::from_fn(|b| (0..3).map(|m| e[a][m] * nadir[m][b]).sum()));
            cameras.push(Camera {
                r,
                c: [500_000.0 + 12.0 * j as f64, 5_300_000.0 + 10.0 * i as f64, 340.0 + 0.3 * noise(n, 3)],
                intrinsics: [F, F, W / 2.0, H / 2.0],
                distortion: [0.0; 6],
            });
        }
    }
    let mut points = Vec::new();
    for k in 0..900 {
        let (x, y) = (-12.0 + 84.0 * uniform(k, 10), -12.0 + 64.0 * uniform(k, 11));
        points.push([500_000.0 + x, 5_300_000.0 + y, 300.0 + ground(x, y)]);
    }
    let at = |x: f64, y: f64| [500_000.0 + x, 5_300_000.0 + y, 300.0 + ground(x, y)];
    let control = vec![at(6.0, 6.0), at(54.0, 6.0), at(6.0, 34.0), at(54.0, 34.0), at(30.0, 20.0)];
    let checks = vec![at(18.0, 12.0), at(42.0, 28.0), at(42.0, 10.0), at(16.0, 30.0)];
    Scene { cameras, points, control, checks }
}

/// A smooth deformation: a bowl and a twist (metres at the area's edge: a few decimetres).
fn bend(p: [f64; 3]) -> [f64; 3] {
    let (x, y) = ((p[0] - 500_030.0) / 30.0, (p[1] - 5_300_020.0) / 20.0);
    [p[0] + 0.05 * y, p[1] - 0.05 * x, p[2] + 0.1 * (x * x + y * y) - 0.1 + 0.1 * x * y]
}

/// Observations of every point every camera sees, with `sigma_px` of noise.
fn observe(cams: &[Camera], pts: &[[f64; 3]], first_point: usize, sigma_px: f64, seed: usize) -> Vec<Observation> {
    let mut v = Vec::new();
    for (j, x) in pts.iter().enumerate() {
        for (i, c) in cams.iter().enumerate() {
            if let Some(q) = project(c, *x).filter(|q| (0.0..W).contains(&q[0]) && (0.0..H).contains(&q[1])) {
                let n = seed + 7919 * j + i;
                v.push(Observation {
                    camera: i,
                    point: first_point + j,
                    px: [q[0] + sigma_px * noise(n, 20), q[1] + sigma_px * noise(n, 21)],
                });
            }
        }
    }
    v
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn problem(s: &Scene, start: impl Fn([f64; 3]) -> [f64; 3]) -> Problem {
    let mut obs = observe(&s.cameras, &s.points, 0, 0.3, 0);
    let nt = s.points.len();
    let gcp_obs = observe(&s.cameras, &s.control, nt, 0.5, 1_000_000);
    assert!(gcp_obs.len() >= 5 * 4, "every control point in several views: {}", gcp_obs.len());
    obs.extend(gcp_obs);
    let cameras = s.cameras.iter().map(|c| Camera { c: start(c.c), ..*c }).collect();
    let mut points: Vec<[f64; 3]> = s.points.iter().map(|p| start(*p)).collect();
    points.extend(s.control.iter().map(|p| start(*p)));
    Problem {
        cameras,
        points,
        observations: obs,
        point_priors: s.control.iter().enumerate().map(|(k, x)| (nt + k, *x, 0.02)).collect(),
        centre_priors: s
            .cameras
            .iter()
            .enumerate()
            .map(|(i, c)| (i, std::array::from_fn(|k| c.c[k] + SHIFT[k] + 0.5 * noise(i, 30 + k))))
            .collect(),
        centre_sigma: 0.5,
    }
}

/// A check point triangulated from the adjusted cameras `cams` (linear least squares over the views where the true
/// cameras `truth` see it).
fn triangulate(cams: &[Camera], truth: &[Camera], x_true: [f64; 3]) -> [f64; 3] {
    // Rays through the exact pixels: what a perfect click gives; the error left is the cameras'.
    let mut a = [[0.0; 3]; 3];
    let mut b = [0.0; 3];
    for (c, t) in cams.iter().zip(truth) {
        let Some(q) = project(t, x_true).filter(|q| (0.0..W).contains(&q[0]) && (0.0..H).contains(&q[1])) else {
            continue;
        };
        let [fx, fy, cx, cy] = c.intrinsics;
        let d_cam = [(q[0] - cx) / fx, (q[1] - cy) / fy, 1.0];
        let d: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| c.r[k][i] * d_cam[k]).sum());
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let d = d.map(|v| v / n);
        for i in 0..3 {
            for j in 0..3 {
                let p = f64::from(u8::from(i == j)) - d[i] * d[j];
                a[i][j] += p;
                b[i] += p * (c.c[j] - x_true[j]);
            }
        }
    }
    // Solved relative to the true point, so that the large coordinates keep their precision.
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d0 = det(a);
    let x: [f64; 3] = std::array::from_fn(|k| {
        let mut m = a;
        (0..3).for_each(|r| m[r][k] = b[r]);
        det(m) / d0
    });
    [x_true[0] + x[0], x_true[1] + x[1], x_true[2] + x[2]]
}

/// Exact pixels of every tie point and of `control`'s points (numbered after the tie points).
fn exact_observations(s: &Scene, control: &[[f64; 3]]) -> Vec<Observation> {
    let mut v = observe(&s.cameras, &s.points, 0, 0.0, 0);
    v.extend(observe(&s.cameras, control, s.points.len(), 0.0, 1_000_000));
    v
}

fn tie_error(s: &Scene, pts: &[[f64; 3]]) -> f64 {
    median(s.points.iter().zip(pts).map(|(t, x)| dist(*t, *x)).collect())
}

/// Exact pixels, control points only: the adjustment undoes the bend to the truth, which the best similarity onto
/// the control points cannot.
#[test]
fn adjustment_on_control_removes_a_bend_no_similarity_can() {
    let s = scene();
    let nt = s.points.len();
    let mut p = problem(&s, bend);
    p.observations = exact_observations(&s, &s.control);
    p.centre_priors.clear();
    let src: Vec<[f64; 3]> = s.control.iter().map(|x| bend(*x)).collect();
    let sim = msnerf::maths::similarity::fit_similarity(&src, &s.control).unwrap();
    let similarity: Vec<[f64; 3]> = p.points[..nt].iter().map(|x| sim.apply(*x)).collect();
    let by_similarity = tie_error(&s, &similarity);
    let sol = adjust(&p).unwrap();
    let tie = tie_error(&s, &sol.points);
    let cams = s.cameras.iter().zip(&sol.cameras).map(|(t, c)| dist(t.c, c.c)).fold(0.0, f64::max);
    let checks: Vec<f64> = s.checks.iter().map(|x| dist(triangulate(&sol.cameras, &s.cameras, *x), *x)).collect();
    println!(
        "bent model after the best similarity: tie points a median {by_similarity:.3} m off; adjusted: {tie:.5} m, \
         worst camera {cams:.5} m, checks {checks:.5?} m, {} iterations, rms {:.2} -> {:.4} px",
        sol.iterations, sol.rms_px_before, sol.rms_px_after
    );
    assert!(by_similarity > 0.04, "the bend must survive a similarity: {by_similarity:.3} m");
    assert!(tie < 1e-3 && cams < 1e-3, "tie points {tie:.5} m, worst camera {cams:.5} m");
    assert!(checks.iter().all(|c| *c < 1e-3), "check points {checks:?}");
    assert!(sol.rms_px_after < 1e-3 && sol.rms_px_before > 0.3, "{} -> {}", sol.rms_px_before, sol.rms_px_after);
}

/// With the images' noise (0.3 px tie points, 0.5 px clicks) and noisy GPS, the adjusted model sits within about
/// a ground sampling distance (0.05 m) of the truth, and check points between the control points likewise.
#[test]
fn adjustment_with_noise_lands_within_a_ground_sample() {
    let s = scene();
    let mut p = problem(&s, bend);
    p.centre_priors.clear();
    let sol = adjust(&p).unwrap();
    let tie = tie_error(&s, &sol.points);
    let checks: Vec<f64> = s.checks.iter().map(|x| dist(triangulate(&sol.cameras, &s.cameras, *x), *x)).collect();
    println!("noisy: tie points {tie:.4} m, checks {checks:.4?} m, rms {:.3} px", sol.rms_px_after);
    assert!(tie < 0.075, "tie points a median {tie:.4} m from the truth");
    assert!(checks.iter().all(|c| *c < 0.1), "check points {checks:?}");
    assert!((0.25..0.45).contains(&sol.rms_px_after), "{}", sol.rms_px_after);
}

/// One control point and the GPS: the point pins the translation, the fixes (with one unknown offset) the rest;
/// the offset found is the datum shift the fixes carry (exact pixels and fixes: to a micrometre).
#[test]
fn one_control_point_and_the_gps_find_the_datum_shift() {
    let s = scene();
    let nt = s.points.len();
    let mut p = problem(&s, bend);
    p.observations = exact_observations(&s, &s.control[..1]);
    p.centre_priors =
        s.cameras.iter().enumerate().map(|(i, c)| (i, std::array::from_fn(|k| c.c[k] + SHIFT[k]))).collect();
    p.point_priors.truncate(1);
    p.points.truncate(nt + 1);
    let sol = adjust(&p).unwrap();
    let off = dist(sol.gps_offset, SHIFT);
    let tie = tie_error(&s, &sol.points[..nt]);
    assert!(off < 1e-6, "GPS offset {:?} against {SHIFT:?}", sol.gps_offset);
    assert!(tie < 1e-4, "tie points a median {tie:.6} m from the truth");
}

#[test]
fn an_unfixed_or_malformed_problem_is_named() {
    let s = scene();
    let mut p = problem(&s, |x| x);
    p.point_priors.clear();
    p.centre_priors.truncate(2);
    assert!(adjust(&p).unwrap_err().contains("fix the frame"));
    let mut p = problem(&s, |x| x);
    p.observations[0].point = p.points.len();
    assert!(adjust(&p).unwrap_err().contains("out of range"));
    let mut p = problem(&s, |x| x);
    p.centre_sigma = 0.0;
    assert!(adjust(&p).unwrap_err().contains("not positive"));
}
