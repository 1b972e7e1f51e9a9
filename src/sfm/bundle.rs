//! Bundle adjustment with ground control: the georeferenced SfM model's cameras and tie points refined together
//! against their image observations, the control points' clicks and surveyed positions, and the GPS fixes, as
//! OpenSfM does for OpenDroneMap when a `gcp_list.txt` is given. A similarity (`super::georef`) cannot remove the
//! model's own deformation (a twist or a bowl of a few decimetres over a small flight); the adjustment can, because
//! the control points pull on the images they were clicked in.
//!
//! The problem, in a local frame (the first camera's centre subtracted, so that UTM's large numbers keep their
//! precision):
//! - each camera: world-to-camera rotation `R` (OpenCV axes) and centre `C`; intrinsics and distortion fixed (the
//!   dataset's calibration);
//! - each observation: `(project(R (X - C)) - px) / PIXEL_SIGMA`, Huber-weighted beyond [`HUBER_PX`] (a tie point
//!   COLMAP kept may still be a mismatch);
//! - each control point: a point of the problem with a prior `(X - surveyed) / CONTROL_SIGMA_M`;
//! - each GPS fix: `(C + b - fix) / gps_sigma` with one offset `b` for the whole flight (the GPS's datum shift, the
//!   same unknown `super::georef` estimates), so that the fixes never pull the flight off the control (the caller,
//!   `super::adjusted`, gives fixes only when too few control points fix the frame).
//!
//! Solver: Levenberg-Marquardt (Marquardt's diagonal scaling) on the normal equations; the points' 3x3 blocks are
//! eliminated (the Schur complement), the reduced camera system (6 per camera, 3 for the offset) is solved densely
//! by Cholesky: 1,800 unknowns for a 300-capture flight.

use crate::maths::linear::cholesky_solve;

/// A tie point's or click's standard deviation, pixels.
pub const PIXEL_SIGMA: f64 = 1.0;
/// Residuals beyond this many pixels weigh as Huber's loss (linearly).
pub const HUBER_PX: f64 = 2.0;
/// Iterations at most.
pub const MAX_ITERATIONS: usize = 50;
/// Converged when an accepted step lowers the cost by less than this fraction (Ceres' `function_tolerance`).
pub const FUNCTION_TOLERANCE: f64 = 1e-6;

/// A camera of the problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// World-to-camera rotation, OpenCV axes (x right, y down, z forward).
    pub r: [[f64; 3]; 3],
    /// Centre, world frame.
    pub c: [f64; 3],
    /// fx, fy, cx, cy (pixels; the image's corner at 0).
    pub intrinsics: [f64; 4],
    /// k1, k2, k3, k4, p1, p2 (`crate::data::camera::distort`).
    pub distortion: [f64; 6],
}

/// One pixel of one point in one camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    pub camera: usize,
    pub point: usize,
    pub px: [f64; 2],
}

/// The adjustment's input.
#[derive(Debug, Clone, Default)]
pub struct Problem {
    pub cameras: Vec<Camera>,
    pub points: Vec<[f64; 3]>,
    pub observations: Vec<Observation>,
    /// (point, surveyed position, standard deviation in metres): the control points.
    pub point_priors: Vec<(usize, [f64; 3], f64)>,
    /// (camera, GPS fix): priors on the centres, with one unknown offset for all.
    pub centre_priors: Vec<(usize, [f64; 3])>,
    /// The fixes' standard deviation, metres.
    pub centre_sigma: f64,
}

/// The adjusted problem and how far it moved.
#[derive(Debug, Clone)]
pub struct Solution {
    pub cameras: Vec<Camera>,
    pub points: Vec<[f64; 3]>,
    /// The GPS fixes' common offset (fix minus centre), metres.
    pub gps_offset: [f64; 3],
    pub iterations: usize,
    /// RMS reprojection error of the observations before and after, pixels.
    pub rms_px_before: f64,
    pub rms_px_after: f64,
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// exp([w]x): Rodrigues' formula, its series below 1e-6 rad.
pub fn rotation_exp(w: [f64; 3]) -> [[f64; 3]; 3] {
    let t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    let t = t2.sqrt();
    let (a, b) = if t < 1e-6 { (1.0 - t2 / 6.0, 0.5 - t2 / 24.0) } else { (t.sin() / t, (1.0 - t.cos()) / t2) };
    let k = [[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]];
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let kk: f64 = (0..3).map(|m| k[i][m] * k[m][j]).sum();
            f64::from(u8::from(i == j)) + a * k[i][j] + b * kk
        })
    })
}

/// The pixel of camera-frame point `p` (None behind the camera).
pub fn project_camera(cam: &Camera, p: [f64; 3]) -> Option<[f64; 2]> {
    if p[2] <= 1e-9 {
        return None;
    }
    let (x, y) = crate::data::camera::distort(p[0] / p[2], p[1] / p[2], &cam.distortion);
    let [fx, fy, cx, cy] = cam.intrinsics;
    Some([fx * x + cx, fy * y + cy])
}

/// The pixel of world point `x` in `cam`.
pub fn project(cam: &Camera, x: [f64; 3]) -> Option<[f64; 2]> {
    project_camera(cam, mat_vec(&cam.r, sub(x, cam.c)))
}

/// d pixel / d camera-frame point (2x3); the distortion's 2x2 part by central differences when there is one.
fn pixel_jacobian(cam: &Camera, p: [f64; 3]) -> [[f64; 3]; 2] {
    let [fx, fy, _, _] = cam.intrinsics;
    let (x, y) = (p[0] / p[2], p[1] / p[2]);
    let dd = if cam.distortion.iter().all(|d| *d == 0.0) {
        [[1.0, 0.0], [0.0, 1.0]]
    } else {
        let h = 1e-7;
        let f = |x: f64, y: f64| crate::data::camera::distort(x, y, &cam.distortion);
        let (xp, yp) = (f(x + h, y), f(x, y + h));
        let (xm, ym) = (f(x - h, y), f(x, y - h));
        [[(xp.0 - xm.0) / (2.0 * h), (yp.0 - ym.0) / (2.0 * h)], [(xp.1 - xm.1) / (2.0 * h), (yp.1 - ym.1) / (2.0 * h)]]
    };
    // d(x, y) / d p
    let iz = 1.0 / p[2];
    let dn = [[iz, 0.0, -x * iz], [0.0, iz, -y * iz]];
    let f = [fx, fy];
    std::array::from_fn(|r| std::array::from_fn(|c| f[r] * (dd[r][0] * dn[0][c] + dd[r][1] * dn[1][c])))
}

/// One observation linearised: its residual (pixels / sigma) and Jacobians, camera (2x6: rotation increment,
/// centre) and point (2x3).
struct Linear {
    r: [f64; 2],
    jc: [[f64; 6]; 2],
    jx: [[f64; 3]; 2],
}

/// [`Linear`] of one observation; None behind the camera.
fn linearise(cam: &Camera, x: [f64; 3], px: [f64; 2]) -> Option<Linear> {
    let p = mat_vec(&cam.r, sub(x, cam.c));
    let q = project_camera(cam, p)?;
    let jp = pixel_jacobian(cam, p);
    // p(dw, dc, dx) = exp(dw) R (x + dx - c - dc): dp/dw = -[p]x, dp/dx = R, dp/dc = -R.
    let skew = [[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]];
    let mut jc = [[0.0; 6]; 2];
    let mut jx = [[0.0; 3]; 2];
    for r in 0..2 {
        for k in 0..3 {
            let mut dw = 0.0;
            let mut dx = 0.0;
            for m in 0..3 {
                dw -= jp[r][m] * skew[m][k];
                dx += jp[r][m] * cam.r[m][k];
            }
            jc[r][k] = dw / PIXEL_SIGMA;
            jc[r][3 + k] = -dx / PIXEL_SIGMA;
            jx[r][k] = dx / PIXEL_SIGMA;
        }
    }
    Some(Linear { r: [(q[0] - px[0]) / PIXEL_SIGMA, (q[1] - px[1]) / PIXEL_SIGMA], jc, jx })
}

/// Huber's weight and loss for a residual of length `n` (in sigmas).
fn huber(n: f64) -> (f64, f64) {
    let k = HUBER_PX / PIXEL_SIGMA;
    if n <= k {
        (1.0, 0.5 * n * n)
    } else {
        (k / n, k * n - 0.5 * k * k)
    }
}

struct State {
    cameras: Vec<Camera>,
    points: Vec<[f64; 3]>,
    offset: [f64; 3],
}

fn cost(p: &Problem, s: &State) -> Option<f64> {
    let mut total = 0.0;
    for o in &p.observations {
        let q = project(&s.cameras[o.camera], s.points[o.point])?;
        total += huber(((q[0] - o.px[0]).hypot(q[1] - o.px[1])) / PIXEL_SIGMA).1;
    }
    for &(j, xyz, sigma) in &p.point_priors {
        let d = sub(s.points[j], xyz);
        total += 0.5 * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / (sigma * sigma);
    }
    for &(i, fix) in &p.centre_priors {
        let c = s.cameras[i].c;
        let d: [f64; 3] = std::array::from_fn(|k| c[k] + s.offset[k] - fix[k]);
        total += 0.5 * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / (p.centre_sigma * p.centre_sigma);
    }
    Some(total)
}

fn rms_px(p: &Problem, s: &State) -> f64 {
    let e: f64 = p
        .observations
        .iter()
        .filter_map(|o| {
            project(&s.cameras[o.camera], s.points[o.point])
                .map(|q| (q[0] - o.px[0]).powi(2) + (q[1] - o.px[1]).powi(2))
        })
        .sum();
    (e / p.observations.len().max(1) as f64).sqrt()
}

/// The linearised problem: the camera block (dense, `n x n`, n = 6 per camera + 3), its gradient, and per point
/// its 3x3 block, gradient and the observations' camera-point blocks.
struct Normal {
    u: Vec<f64>,
    gc: Vec<f64>,
    v: Vec<[[f64; 3]; 3]>,
    gp: Vec<[f64; 3]>,
    /// Per observation: (camera, point, 6x3 block).
    w: Vec<(usize, usize, [[f64; 3]; 6])>,
    /// Per point, its observations (indices into `w`).
    by_point: Vec<Vec<usize>>,
}

fn assemble(p: &Problem, s: &State) -> Option<Normal> {
    let nc = p.cameras.len();
    let n = 6 * nc + 3;
    let mut u = vec![0.0; n * n];
    let mut gc = vec![0.0; n];
    let mut v = vec![[[0.0; 3]; 3]; p.points.len()];
    let mut gp = vec![[0.0; 3]; p.points.len()];
    let mut w = Vec::with_capacity(p.observations.len());
    for o in &p.observations {
        let Linear { r, jc, jx } = linearise(&s.cameras[o.camera], s.points[o.point], o.px)?;
        let (wt, _) = huber(r[0].hypot(r[1]));
        let base = 6 * o.camera;
        let mut blk = [[0.0; 3]; 6];
        for a in 0..6 {
            for b in 0..6 {
                u[(base + a) * n + base + b] += wt * (jc[0][a] * jc[0][b] + jc[1][a] * jc[1][b]);
            }
            for b in 0..3 {
                blk[a][b] = wt * (jc[0][a] * jx[0][b] + jc[1][a] * jx[1][b]);
            }
            gc[base + a] += wt * (jc[0][a] * r[0] + jc[1][a] * r[1]);
        }
        for a in 0..3 {
            for b in 0..3 {
                v[o.point][a][b] += wt * (jx[0][a] * jx[0][b] + jx[1][a] * jx[1][b]);
            }
            gp[o.point][a] += wt * (jx[0][a] * r[0] + jx[1][a] * r[1]);
        }
        w.push((o.camera, o.point, blk));
    }
    for &(j, xyz, sigma) in &p.point_priors {
        let iw = 1.0 / (sigma * sigma);
        for a in 0..3 {
            v[j][a][a] += iw;
            gp[j][a] += iw * (s.points[j][a] - xyz[a]);
        }
    }
    let iw = 1.0 / (p.centre_sigma * p.centre_sigma);
    let ob = 6 * nc;
    for &(i, fix) in &p.centre_priors {
        let c = 6 * i + 3;
        for k in 0..3 {
            let r = s.cameras[i].c[k] + s.offset[k] - fix[k];
            u[(c + k) * n + c + k] += iw;
            u[(c + k) * n + ob + k] += iw;
            u[(ob + k) * n + c + k] += iw;
            u[(ob + k) * n + ob + k] += iw;
            gc[c + k] += iw * r;
            gc[ob + k] += iw * r;
        }
    }
    if p.centre_priors.is_empty() {
        // No fixes: the offset is not a parameter.
        for k in 0..3 {
            u[(ob + k) * n + ob + k] = 1.0;
        }
    }
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); p.points.len()];
    for (k, (_, j, _)) in w.iter().enumerate() {
        by_point[*j].push(k);
    }
    Some(Normal { u, gc, v, gp, w, by_point })
}

fn inv3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |i: usize, j: usize| {
        let (a, b) = ((i + 1) % 3, (i + 2) % 3);
        let (x, y) = ((j + 1) % 3, (j + 2) % 3);
        m[a][x] * m[b][y] - m[a][y] * m[b][x]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    if !det.is_finite() || det.abs() < 1e-300 {
        return None;
    }
    Some(std::array::from_fn(|i| std::array::from_fn(|j| c(j, i) / det)))
}

/// One damped step: the increments of the cameras (6 each, then the offset) and the points; None when the damped
/// system is not positive definite.
fn step(p: &Problem, nm: &Normal, lambda: f64) -> Option<(Vec<f64>, Vec<[f64; 3]>)> {
    let n = nm.gc.len();
    let mut s = nm.u.clone();
    for i in 0..n {
        s[i * n + i] += lambda * nm.u[i * n + i] + 1e-12;
    }
    let mut rhs: Vec<f64> = nm.gc.iter().map(|g| -g).collect();
    let vinv: Vec<[[f64; 3]; 3]> =
        nm.v.iter()
            .map(|v| {
                let mut d = *v;
                (0..3).for_each(|a| d[a][a] += lambda * v[a][a] + 1e-12);
                inv3(&d)
            })
            .collect::<Option<_>>()?;
    for (j, obs) in nm.by_point.iter().enumerate() {
        let vi = &vinv[j];
        // W_o V^-1 for each observation of the point (6x3).
        let wv: Vec<[[f64; 3]; 6]> = obs
            .iter()
            .map(|&k| {
                let b = &nm.w[k].2;
                std::array::from_fn(|a| std::array::from_fn(|c| (0..3).map(|m| b[a][m] * vi[m][c]).sum()))
            })
            .collect();
        for (x, &ka) in obs.iter().enumerate() {
            let ia = 6 * nm.w[ka].0;
            for a in 0..6 {
                rhs[ia + a] += (0..3).map(|m| wv[x][a][m] * nm.gp[j][m]).sum::<f64>();
            }
            for &kb in obs {
                let ib = 6 * nm.w[kb].0;
                let b = &nm.w[kb].2;
                for a in 0..6 {
                    for c in 0..6 {
                        s[(ia + a) * n + ib + c] -= (0..3).map(|m| wv[x][a][m] * b[c][m]).sum::<f64>();
                    }
                }
            }
        }
    }
    let dc = cholesky_solve(s, rhs)?;
    let dx = (0..p.points.len())
        .map(|j| {
            let mut g = nm.gp[j].map(|v| -v);
            for &k in &nm.by_point[j] {
                let (i, _, b) = &nm.w[k];
                for m in 0..3 {
                    g[m] -= (0..6).map(|a| b[a][m] * dc[6 * i + a]).sum::<f64>();
                }
            }
            mat_vec(&vinv[j], g)
        })
        .collect();
    Some((dc, dx))
}

fn apply(s: &State, dc: &[f64], dx: &[[f64; 3]]) -> State {
    let cameras = s
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let e = rotation_exp([dc[6 * i], dc[6 * i + 1], dc[6 * i + 2]]);
            let r = std::array::from_fn(|a| std::array::from_fn(|b| (0..3).map(|m| e[a][m] * c.r[m][b]).sum()));
            Camera { r, c: std::array::from_fn(|k| c.c[k] + dc[6 * i + 3 + k]), ..*c }
        })
        .collect();
    let ob = dc.len() - 3;
    State {
        cameras,
        points: s.points.iter().zip(dx).map(|(x, d)| [x[0] + d[0], x[1] + d[1], x[2] + d[2]]).collect(),
        offset: std::array::from_fn(|k| s.offset[k] + dc[ob + k]),
    }
}

/// Adjusts `p`; errors name what makes the problem unsolvable.
pub fn adjust(p: &Problem) -> Result<Solution, String> {
    if let Some(o) = p.observations.iter().find(|o| o.camera >= p.cameras.len() || o.point >= p.points.len()) {
        return Err(format!("observation of point {} in camera {} is out of range", o.point, o.camera));
    }
    if p.point_priors.is_empty() && p.centre_priors.len() < 3 {
        return Err("neither control points nor three GPS fixes fix the frame".into());
    }
    let sigma_ok = p.centre_sigma.is_finite() && p.centre_sigma > 0.0;
    if !p.centre_priors.is_empty() && !sigma_ok {
        return Err(format!("GPS standard deviation {} m is not positive", p.centre_sigma));
    }
    // The local frame.
    let origin = p.cameras.first().map_or([0.0; 3], |c| c.c);
    let local = Problem {
        cameras: p.cameras.iter().map(|c| Camera { c: sub(c.c, origin), ..*c }).collect(),
        points: p.points.iter().map(|x| sub(*x, origin)).collect(),
        point_priors: p.point_priors.iter().map(|&(j, x, s)| (j, sub(x, origin), s)).collect(),
        centre_priors: p.centre_priors.iter().map(|&(i, x)| (i, sub(x, origin))).collect(),
        ..p.clone()
    };
    let p = &local;
    // The offset starts at the fixes' mean offset.
    let offset = if p.centre_priors.is_empty() {
        [0.0; 3]
    } else {
        let n = p.centre_priors.len() as f64;
        std::array::from_fn(|k| p.centre_priors.iter().map(|&(i, f)| f[k] - p.cameras[i].c[k]).sum::<f64>() / n)
    };
    let mut s = State { cameras: p.cameras.clone(), points: p.points.clone(), offset };
    let rms_px_before = rms_px(p, &s);
    let mut c0 = cost(p, &s).ok_or("a point lies behind a camera that observes it")?;
    let mut lambda = 1e-4;
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        let nm = assemble(p, &s).ok_or("a point lies behind a camera that observes it")?;
        let mut improved = false;
        for _ in 0..12 {
            if let Some((dc, dx)) = step(p, &nm, lambda) {
                let next = apply(&s, &dc, &dx);
                if let Some(c1) = cost(p, &next).filter(|c1| *c1 <= c0) {
                    let done = c0 - c1 <= FUNCTION_TOLERANCE * c0.max(1e-12);
                    s = next;
                    c0 = c1;
                    lambda = (lambda / 3.0).max(1e-12);
                    improved = !done;
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let rms_px_after = rms_px(p, &s);
    let add = |x: [f64; 3]| [x[0] + origin[0], x[1] + origin[1], x[2] + origin[2]];
    Ok(Solution {
        cameras: s.cameras.iter().map(|c| Camera { c: add(c.c), ..*c }).collect(),
        points: s.points.iter().map(|x| add(*x)).collect(),
        gps_offset: s.offset,
        iterations,
        rms_px_before,
        rms_px_after,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The analytic Jacobians against central differences of the residual.
    #[test]
    fn jacobians_match_finite_differences() {
        let cam = Camera {
            r: rotation_exp([0.1, -0.2, 0.05]),
            c: [1.0, -2.0, -30.0],
            intrinsics: [500.0, 510.0, 160.0, 120.0],
            distortion: [0.05, -0.01, 0.0, 0.0, 0.001, -0.002],
        };
        let x = [2.0, 1.0, 3.0];
        let px = [100.0, 90.0];
        let Linear { r: r0, jc, jx } = linearise(&cam, x, px).unwrap();
        let h = 1e-6;
        for k in 0..6 {
            let mut d = [0.0; 6];
            d[k] = h;
            let f = |sign: f64| {
                let e = rotation_exp([sign * d[0], sign * d[1], sign * d[2]]);
                let r = std::array::from_fn(|a| std::array::from_fn(|b| (0..3).map(|m| e[a][m] * cam.r[m][b]).sum()));
                let c = Camera { r, c: std::array::from_fn(|i| cam.c[i] + sign * d[3 + i]), ..cam };
                linearise(&c, x, px).unwrap().r
            };
            let (a, b) = (f(1.0), f(-1.0));
            for r in 0..2 {
                let num = (a[r] - b[r]) / (2.0 * h);
                assert!((num - jc[r][k]).abs() < 1e-4 * (1.0 + num.abs()), "camera {k} row {r}: {num} vs {}", jc[r][k]);
            }
        }
        for k in 0..3 {
            let f = |sign: f64| {
                let mut y = x;
                y[k] += sign * h;
                linearise(&cam, y, px).unwrap().r
            };
            let (a, b) = (f(1.0), f(-1.0));
            for r in 0..2 {
                let num = (a[r] - b[r]) / (2.0 * h);
                assert!((num - jx[r][k]).abs() < 1e-4 * (1.0 + num.abs()), "point {k} row {r}: {num} vs {}", jx[r][k]);
            }
        }
        assert!(r0.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn rotation_exp_is_a_rotation_about_its_axis() {
        let w = [0.3, -0.4, 1.2];
        let r = rotation_exp(w);
        let rw = mat_vec(&r, w);
        assert!((0..3).all(|k| (rw[k] - w[k]).abs() < 1e-12));
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|m| r[m][i] * r[m][j]).sum();
                assert!((d - f64::from(u8::from(i == j))).abs() < 1e-12);
            }
        }
    }
}
