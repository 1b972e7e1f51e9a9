//! The export's photometric refinement (`msnerf::nerf::refine`), on the CPU:
//! - `ncc` against Pearson's correlation written from its textbook sum form in plain f64, its blindness to gain and
//!   offset, and its refusal of a flat patch;
//! - `bilinear` against the interpolation formula at random positions, and None off the pixel centres' hull;
//! - on a textured ground plane (z = 0) seen by four pinhole cameras, rendered here by intersecting each pixel's ray
//!   with the plane: a point started 4 footprints in front of the plane comes back onto it within 0.1 footprint,
//!   and a texture a hundred times darker and weaker gives the same answer; a uniform plane, a start beyond the
//!   search range, and too few partner views leave the point where it was, unsupported; a best correlation below the
//!   move threshold leaves it there too, supported;
//! - the trend removed from each patch against a least-squares polynomial fitted here from the normal equations, and
//!   a uniform plane under smooth shading (an albedo ramp, view-dependent shading, noise), which plain NCC correlates
//!   at every height and the default leaves unsupported.

use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::nerf::refine::{bilinear, ncc, refine, PatchView, RefineOptions};
use msnerf::sim::cameras::look_at;
use rand::{Rng, SeedableRng};

/// Pearson's r from the raw sums (a different arrangement from the library's centred sums).
fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (sa, sb) = (a.iter().sum::<f64>(), b.iter().sum::<f64>());
    let sab: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let (saa, sbb) = (a.iter().map(|x| x * x).sum::<f64>(), b.iter().map(|y| y * y).sum::<f64>());
    (n * sab - sa * sb) / ((n * saa - sa * sa) * (n * sbb - sb * sb)).sqrt()
}

#[test]
fn ncc_is_pearsons_r_blind_to_gain_and_offset() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for _ in 0..50 {
        let a: Vec<f64> = (0..49).map(|_| rng.random::<f64>()).collect();
        let b: Vec<f64> = a.iter().map(|x| 0.6 * x + 0.4 * rng.random::<f64>()).collect();
        let r = ncc(&a, &b).expect("varying patches");
        assert!((r - pearson(&a, &b)).abs() < 1e-12, "{r} against {}", pearson(&a, &b));
        let dark: Vec<f64> = b.iter().map(|x| 0.003 * x + 0.02).collect();
        assert!((ncc(&a, &dark).unwrap() - r).abs() < 1e-9, "gain and offset change the NCC");
    }
    assert_eq!(ncc(&[0.3; 49], &[0.1; 49]), None, "a flat patch has no correlation");
}

#[test]
fn bilinear_matches_the_formula() {
    let (w, h) = (7u32, 5u32);
    let plane: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 * 0.1).collect();
    let at = |c: usize, r: usize| plane[r * w as usize + c] as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for _ in 0..200 {
        let (u, v) = (rng.random_range(0.5..w as f64 - 0.5), rng.random_range(0.5..h as f64 - 0.5));
        let (x, y) = (u - 0.5, v - 0.5);
        let (c0, r0) = ((x.floor() as usize).min(w as usize - 2), (y.floor() as usize).min(h as usize - 2));
        let (fx, fy) = (x - c0 as f64, y - r0 as f64);
        let want = at(c0, r0) * (1.0 - fx) * (1.0 - fy)
            + at(c0 + 1, r0) * fx * (1.0 - fy)
            + at(c0, r0 + 1) * (1.0 - fx) * fy
            + at(c0 + 1, r0 + 1) * fx * fy;
        let got = bilinear(&plane, w, h, u, v).expect("inside");
        assert!((got - want).abs() < 1e-12, "({u}, {v}): {got} against {want}");
    }
    assert_eq!(bilinear(&plane, w, h, 0.49, 2.0), None);
    assert_eq!(bilinear(&plane, w, h, 3.0, h as f64 - 0.49), None);
}

const W: u32 = 96;
const H: u32 = 72;

fn camera() -> Camera {
    Camera {
        model: CameraModel::Pinhole,
        fx: 110.0,
        fy: 110.0,
        cx: W as f64 / 2.0,
        cy: H as f64 / 2.0,
        width: W,
        height: H,
        distortion: Distortion::default(),
    }
}

/// Smooth texture with two octaves (periods of about 7 m and 1.6 m).
fn texture(x: f64, y: f64) -> f64 {
    (0.9 * x + 0.3).sin() * (0.7 * y).cos() + 0.5 * (0.37 * x + 1.1 * y).sin() + 0.3 * (3.9 * x - 2.1 * y).sin()
}

/// One band: `value(ray direction, the point where the pixel's ray meets the plane z = 0)` per pixel.
fn render_plane(cam: &Camera, c2w: &[[f64; 4]; 4], mut value: impl FnMut([f64; 3], [f64; 3]) -> f64) -> Vec<f32> {
    let mut img = Vec::with_capacity((W * H) as usize);
    for row in 0..H {
        for col in 0..W {
            let ray = cam.ray_f64(c2w, row, col);
            let t = -ray.origin[2] / ray.direction[2];
            let p = [0, 1, 2].map(|k| ray.origin[k] + t * ray.direction[k]);
            img.push(value(ray.direction, p) as f32);
        }
    }
    img
}

/// One band: every pixel's ray meets the plane z = 0 at the texture `base + amp * texture`.
fn render(cam: &Camera, c2w: &[[f64; 4]; 4], base: f64, amp: f64) -> Vec<f32> {
    render_plane(cam, c2w, |_, p| base + amp * texture(p[0], p[1]))
}

struct Scene {
    cam: Camera,
    poses: Vec<[[f64; 4]; 4]>,
    images: Vec<Vec<f32>>,
}

fn scene(base: f64, amp: f64) -> Scene {
    let cam = camera();
    let eyes = [[0.0, -16.0, 22.0], [13.0, -6.0, 22.0], [-13.0, -7.0, 21.0], [2.0, 12.0, 23.0]];
    let poses: Vec<_> = eyes.iter().map(|&e| look_at(e, [0.0, 0.0, 0.0], None)).collect();
    let images = poses.iter().map(|p| render(&cam, p, base, amp)).collect();
    Scene { cam, poses, images }
}

impl Scene {
    fn views(&self, n: usize) -> Vec<PatchView<'_>> {
        self.poses[..n]
            .iter()
            .zip(&self.images)
            .map(|(m, img)| PatchView {
                origin: [m[0][3], m[1][3], m[2][3]],
                rot: [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]),
                cam: &self.cam,
                planes: vec![img.as_slice()],
            })
            .collect()
    }

    /// The reference camera's ray through pixel (row, col): origin, direction, distance to the plane, footprint.
    fn ray(&self, row: u32, col: u32) -> ([f64; 3], [f64; 3], f64, f64) {
        let r = self.cam.ray_f64(&self.poses[0], row, col);
        let t = -r.origin[2] / r.direction[2];
        (r.origin, r.direction, t, t / self.cam.fx)
    }
}

/// Starts `offset` footprints along the ray from the plane (negative: in front) and refines.
fn refine_from(s: &Scene, offset: f64, views: usize, opts: &RefineOptions) -> (msnerf::nerf::refine::Refined, f64) {
    let (o, d, t, fp) = s.ray(30, 50);
    let p0 = [0, 1, 2].map(|k| o[k] + (t + offset * fp) * d[k]);
    (refine(p0, d, [0.0, 0.0, 1.0], fp, &s.views(views), opts), fp)
}

#[test]
fn a_point_in_front_of_a_textured_plane_comes_back_onto_it() {
    let opts = RefineOptions::default();
    let bright = scene(0.4, 0.15);
    let (r, fp) = refine_from(&bright, -4.0, 4, &opts);
    eprintln!("bright: moved {} by {:.4} footprints, NCC {:.4}", r.moved, r.s / fp, r.ncc);
    assert!(r.moved && r.ncc > 0.9, "{r:?}");
    assert!((r.s / fp - 4.0).abs() < 0.1, "ended {:.3} footprints off the plane", r.s / fp - 4.0);
    // The DSM's refinement removes each patch's quadratic trend: this two-octave texture keeps its finer octave,
    // which the images' bilinear sampling blurs by a different phase per view, so within 0.15 footprint.
    let dsm = RefineOptions { drop_unsupported: true, ..RefineOptions::dsm() };
    let (detrended, _) = refine_from(&bright, -4.0, 4, &dsm);
    assert!(detrended.moved && (detrended.s / fp - 4.0).abs() < 0.15, "trend removed: {detrended:?}");
    // Behind the plane too.
    let (r2, _) = refine_from(&bright, 3.0, 4, &opts);
    assert!(r2.moved && (r2.s / fp + 3.0).abs() < 0.1, "from behind: {r2:?}");

    // A hundred times darker and weaker: the same surface (NCC is blind to gain and offset; an MSE is not).
    let dark = scene(0.004, 0.0015);
    let (rd, _) = refine_from(&dark, -4.0, 4, &opts);
    assert!(rd.moved && (rd.s - r.s).abs() < 0.02 * fp, "dark texture: {rd:?} against {r:?}");
}

#[test]
fn without_support_the_point_stays() {
    let opts = RefineOptions::default();
    // A uniform plane: nothing to correlate.
    let (r, _) = refine_from(&scene(0.3, 0.0), -4.0, 4, &opts);
    assert!(!r.moved && r.s == 0.0 && r.ncc.is_nan(), "uniform plane: {r:?}");
    // The surface beyond the range: the best score lies at its end.
    let bright = scene(0.4, 0.15);
    let (r, _) = refine_from(&bright, -12.0, 4, &opts);
    assert!(!r.moved && !r.supported && r.s == 0.0, "surface 12 footprints away with a range of 8: {r:?}");
    // One partner view where two are needed.
    let (r, _) = refine_from(&bright, -4.0, 2, &opts);
    assert!(!r.moved && !r.supported, "one partner: {r:?}");
    let (r, _) = refine_from(&bright, -4.0, 2, &RefineOptions { min_views: 1, ..opts.clone() });
    assert!(r.moved, "one partner allowed: {r:?}");
    // A threshold no correlation reaches.
    let (r, _) = refine_from(&bright, -4.0, 4, &RefineOptions { min_ncc: 1.0, ..opts });
    assert!(!r.moved && !r.supported, "min_ncc 1: {r:?}");
}

#[test]
fn a_weak_correlation_supports_the_point_without_moving_it() {
    // The same refinement with the move threshold just above and just below the correlation it reaches.
    let bright = scene(0.4, 0.15);
    let (free, fp) = refine_from(&bright, -4.0, 4, &RefineOptions { move_ncc: -1.0, ..Default::default() });
    assert!(free.moved && free.supported && (free.s / fp - 4.0).abs() < 0.1, "{free:?}");
    let above = RefineOptions { move_ncc: free.ncc + 1e-9, ..Default::default() };
    let (r, _) = refine_from(&bright, -4.0, 4, &above);
    assert!(r.supported && !r.moved && r.s == 0.0, "a best NCC below move_ncc keeps the point: {r:?}");
    assert_eq!(r.ncc, free.ncc, "and reports the NCC it reached");
    let below = RefineOptions { move_ncc: free.ncc - 1e-9, ..Default::default() };
    let (r, _) = refine_from(&bright, -4.0, 4, &below);
    assert!(r.moved && r.s == free.s, "at or above move_ncc the point moves: {r:?}");
    // Unsupported is not supported: a uniform plane.
    let (r, _) = refine_from(&scene(0.3, 0.0), -4.0, 4, &RefineOptions::default());
    assert!(!r.supported && !r.moved, "{r:?}");
}

/// `holds_sweep` says whether a reference view would score every candidate of the sweep: checked against the sweep
/// itself (the patch scored against the view's own copy at every coarse candidate) for points across a nadir and an
/// oblique camera's frame, the border rows and columns included.
#[test]
fn a_reference_holds_the_sweep_exactly_when_every_candidate_scores() {
    use msnerf::nerf::refine::{holds_sweep, plane_axes, score};
    let cam = camera();
    let opts = RefineOptions::default();
    let (down, up) = ([0.0, 0.0, -1.0], [0.0, 0.0, 1.0]);
    let mut seen = [0usize; 2];
    for eye in [[0.0, 0.0, 20.0], [12.0, -5.0, 18.0]] {
        let m = look_at(eye, [0.0, 0.0, 0.0], None);
        let img = render(&cam, &m, 0.5, 0.2);
        let v = PatchView {
            origin: [m[0][3], m[1][3], m[2][3]],
            rot: [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]),
            cam: &cam,
            planes: vec![img.as_slice()],
        };
        for row in (0..H).step_by(3) {
            for col in (0..W).step_by(3) {
                let r = cam.ray_f64(&m, row, col);
                let t = -r.origin[2] / r.direction[2];
                let p0 = [0, 1, 2].map(|k| r.origin[k] + t * r.direction[k]);
                let holds = holds_sweep(&cam, v.origin, &v.rot, p0, down, up, &opts);
                let fp = t / cam.fx;
                let pair =
                    [PatchView { planes: vec![img.as_slice()], ..v }, PatchView { planes: vec![img.as_slice()], ..v }];
                let mut scratch = Vec::new();
                let all = (-(opts.range as i64)..=opts.range as i64).all(|k| {
                    let p = [p0[0], p0[1], p0[2] + k as f64 * fp * down[2]];
                    score(p, plane_axes(up), fp, opts.half, &[], &pair, &mut scratch).0.is_some()
                });
                assert_eq!(holds, all, "pixel ({row}, {col}) of the camera at {eye:?}");
                seen[holds as usize] += 1;
            }
        }
    }
    assert!(seen[0] > 50 && seen[1] > 200, "both outcomes met: {seen:?}");
}

/// One band over the plane z = 0: a smooth albedo ramp (a 38 m period: nearly linear over a patch), `amp` of the
/// texture, shading that depends on the viewing direction only (a lobe about one direction, the same for every
/// view: it moves with the camera and lies at no height), and sensor noise of standard deviation `noise` (a sum of 12
/// uniforms).
fn render_shaded(cam: &Camera, c2w: &[[f64; 4]; 4], amp: f64, noise: f64, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let lobe = glam::DVec3::new(0.35, -0.2, -0.9).normalize();
    render_plane(cam, c2w, |dir, p| {
        let ramp = 0.05 * (p[0] / 6.0 + 0.4 * p[1] / 6.0).sin();
        let shade = 0.02 * (1.0 + glam::DVec3::from(dir).normalize().dot(lobe)).powi(3);
        let n: f64 = (0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0;
        0.3 + ramp + shade + amp * texture(p[0], p[1]) + noise * n
    })
}

fn shaded_scene(amp: f64, noise: f64) -> Scene {
    let cam = camera();
    let eyes = [[0.0, -16.0, 22.0], [13.0, -6.0, 22.0], [-13.0, -7.0, 21.0], [2.0, 12.0, 23.0]];
    let poses: Vec<_> = eyes.iter().map(|&e| look_at(e, [0.0, 0.0, 0.0], None)).collect();
    let images = poses.iter().enumerate().map(|(i, p)| render_shaded(&cam, p, amp, noise, 11 + i as u64)).collect();
    Scene { cam, poses, images }
}

/// A uniform plane whose brightness varies smoothly (an albedo ramp, view-dependent shading, noise): plain NCC (no
/// trend removed, the cloud's default) correlates above 0.9 at every height of the sweep, so its best score places
/// nothing; with the DSM's quadratic trend removed only the noise is left and the point is unsupported. A textured
/// plane under the same ramp, shading and noise still comes back onto itself.
#[test]
fn smooth_shading_is_not_texture() {
    use msnerf::nerf::refine::{plane_axes, score, trend_basis};
    let uniform = shaded_scene(0.0, 2e-4);
    let (o, d, t, fp) = uniform.ray(30, 50);
    let views = uniform.views(4);
    let opts = RefineOptions { drop_unsupported: true, ..RefineOptions::dsm() };
    let mut scratch = Vec::new();
    let sweep = |trend: &[Vec<f64>], scratch: &mut Vec<f64>| -> Vec<f64> {
        (-(opts.range as i64)..=opts.range as i64)
            .map(|k| {
                let p = [0, 1, 2].map(|i| o[i] + (t + k as f64 * fp) * d[i]);
                score(p, plane_axes([0.0, 0.0, 1.0]), fp, opts.half, trend, &views, scratch).0.unwrap_or(f64::NAN)
            })
            .collect()
    };
    let plain = sweep(&[], &mut scratch);
    eprintln!("plain NCC along the sweep: {plain:.3?}");
    assert!(plain.iter().all(|&c| c > 0.9), "plain NCC should correlate the ramp at every height: {plain:.3?}");
    let detrended = sweep(&trend_basis(2 * opts.half + 1, opts.trend_degree), &mut scratch);
    eprintln!("with the quadratic trend removed: {detrended:.3?}");
    assert!(detrended.iter().all(|&c| c < opts.min_ncc), "{detrended:.3?}");
    let (r, _) = refine_from(&uniform, -4.0, 4, &opts);
    assert!(!r.supported && !r.moved, "{r:?}");

    let textured = shaded_scene(0.05, 2e-4);
    let (r, fp) = refine_from(&textured, -4.0, 4, &opts);
    eprintln!("textured: {r:?}");
    assert!(r.moved && (r.s / fp - 4.0).abs() < 0.15, "textured under shading: {r:?}");
}

/// `remove_trend(trend_basis(side, 2))` leaves the residual of the least-squares quadratic, computed here from the
/// normal equations (Gaussian elimination with partial pivoting, plain f64); degree 1 likewise with a plane.
#[test]
fn the_trend_removed_is_the_least_squares_polynomial() {
    use msnerf::nerf::refine::{remove_trend, trend_basis};
    let side = 7;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for degree in [1usize, 2] {
        let terms: Vec<(i32, i32)> = (0..=degree as i32).flat_map(|d| (0..=d).map(move |px| (px, d - px))).collect();
        for _ in 0..20 {
            let patch: Vec<f64> = (0..side * side).map(|_| rng.random::<f64>()).collect();
            let h = (side as f64 - 1.0) / 2.0;
            let row = |k: usize| -> Vec<f64> {
                let (x, y) = ((k / side) as f64 - h, (k % side) as f64 - h);
                terms.iter().map(|&(a, b)| x.powi(a) * y.powi(b)).collect()
            };
            let n = terms.len();
            let mut m = vec![vec![0.0; n + 1]; n];
            for (k, &v) in patch.iter().enumerate() {
                let r = row(k);
                for i in 0..n {
                    for j in 0..n {
                        m[i][j] += r[i] * r[j];
                    }
                    m[i][n] += r[i] * v;
                }
            }
            for c in 0..n {
                let p = (c..n).max_by(|&a, &b| m[a][c].abs().total_cmp(&m[b][c].abs())).unwrap();
                m.swap(c, p);
                let pivot = m[c].clone();
                for (r, row) in m.iter_mut().enumerate() {
                    if r != c {
                        let f = row[c] / pivot[c];
                        row.iter_mut().zip(&pivot).skip(c).for_each(|(x, p)| *x -= f * p);
                    }
                }
            }
            let coef: Vec<f64> = (0..n).map(|i| m[i][n] / m[i][i]).collect();
            let mut got = patch.clone();
            remove_trend(&mut got, &trend_basis(side, degree));
            for (k, &v) in patch.iter().enumerate() {
                let fit: f64 = row(k).iter().zip(&coef).map(|(a, b)| a * b).sum();
                assert!(
                    (got[k] - (v - fit)).abs() < 1e-10,
                    "degree {degree}, sample {k}: {} against {}",
                    got[k],
                    v - fit
                );
            }
        }
    }
    assert_eq!(trend_basis(1, 2).len(), 1, "a one-sample patch holds only the constant");
}
