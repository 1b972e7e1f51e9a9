//! Band-to-band registration: a homography per band mapping the reference band's target pixels to the band's
//! (undistorted, target-camera) pixels.
//!
//! - **Initial guess** from the rig: `H = K_t R_rel K_t^-1` from `Camera:RigRelatives` (rotation only, exact
//!   at infinity: MicaSense's `get_homography`), plus DJI's `RelativeOpticalCenter` shift; identity when the
//!   files carry neither. Then a coarse translation search (normalised cross-correlation over +-12 pixels at
//!   1/8 resolution) takes up whatever the rig data missed.
//! - **Refinement**, an ECC-equivalent Gauss-Newton alignment: on gradient-magnitude images (edges agree
//!   across bands where intensities do not: vegetation is dark in red and bright in NIR) and on a four-level
//!   pyramid, it minimises `sum (alpha * I(H u) + beta - T(u))^2` over the 8 homography parameters, refitting
//!   the photometric gain and offset (alpha, beta) every iteration. ECC maximises the correlation coefficient,
//!   which is the same optimum for this affine photometric model; solving for alpha and beta directly keeps
//!   one small normal-equation system per iteration. Coordinates are normalised to [-1, 1] at every level so the
//!   perspective terms stay well conditioned.
//! - **Residual field**: a smooth grid of local shifts on top of the homography ([`super::warp`], [`fit_field`]).
//! - **Residual**: after alignment a translation-only Lucas-Kanade on each image quadrant measures the shift
//!   that is left; the largest is reported per band, with and without the field.

/// A 3x3 homography, row-major, `h[8]` = 1.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Homography(pub [f64; 9]);

impl Homography {
    pub const IDENTITY: Homography = Homography([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);

    pub fn translation(dx: f64, dy: f64) -> Homography {
        Homography([1.0, 0.0, dx, 0.0, 1.0, dy, 0.0, 0.0, 1.0])
    }

    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let h = &self.0;
        let d = h[6] * x + h[7] * y + h[8];
        ((h[0] * x + h[1] * y + h[2]) / d, (h[3] * x + h[4] * y + h[5]) / d)
    }

    pub fn mul(&self, o: &Homography) -> Homography {
        let (a, b) = (&self.0, &o.0);
        let mut r = [0.0; 9];
        for i in 0..3 {
            for j in 0..3 {
                r[i * 3 + j] = (0..3).map(|k| a[i * 3 + k] * b[k * 3 + j]).sum();
            }
        }
        Homography(r).normalized()
    }

    pub fn normalized(self) -> Homography {
        let s = self.0[8];
        Homography(self.0.map(|v| v / s))
    }

    pub fn inverse(&self) -> Option<Homography> {
        let m = &self.0;
        let c = [
            m[4] * m[8] - m[5] * m[7],
            m[2] * m[7] - m[1] * m[8],
            m[1] * m[5] - m[2] * m[4],
            m[5] * m[6] - m[3] * m[8],
            m[0] * m[8] - m[2] * m[6],
            m[2] * m[3] - m[0] * m[5],
            m[3] * m[7] - m[4] * m[6],
            m[1] * m[6] - m[0] * m[7],
            m[0] * m[4] - m[1] * m[3],
        ];
        let det = m[0] * c[0] + m[1] * c[3] + m[2] * c[6];
        (det.abs() > 1e-15).then(|| Homography(c.map(|v| v / det)).normalized())
    }

    /// The same map in coordinates scaled by `s` (`S H S^-1`, S = diag(s, s, 1)).
    pub fn scaled(&self, s: f64) -> Homography {
        let h = &self.0;
        Homography([h[0], h[1], h[2] * s, h[3], h[4], h[5] * s, h[6] / s, h[7] / s, h[8]])
    }
}

/// `K_t R K_t^-1` for a rig rotation given as MicaSense writes `RigRelatives` (degrees about x, y, z, composed
/// as Rx * Ry * Rz) in a target camera of focal length `f` and principal point (cx, cy). Maps reference pixels
/// to band pixels.
pub fn rig_homography(rel_deg: [f64; 3], f: f64, cx: f64, cy: f64) -> Homography {
    let [a, b, c] = rel_deg.map(f64::to_radians);
    let rx = glam::DMat3::from_rotation_x(a);
    let ry = glam::DMat3::from_rotation_y(b);
    let rz = glam::DMat3::from_rotation_z(c);
    let r = rx * ry * rz;
    let k = glam::DMat3::from_cols(
        glam::DVec3::new(f, 0.0, 0.0),
        glam::DVec3::new(0.0, f, 0.0),
        glam::DVec3::new(cx, cy, 1.0),
    );
    // MicaSense: the band's rays are R^T applied to the reference's (R rotates band -> reference).
    let h = k * r.transpose() * k.inverse();
    let c = h.to_cols_array(); // column-major
    Homography([c[0], c[3], c[6], c[1], c[4], c[7], c[2], c[5], c[8]]).normalized()
}

/// A point and where it maps to.
pub type PointPair = ((f64, f64), (f64, f64));

/// The least-squares homography mapping `pairs[k].0` to `pairs[k].1` (the algebraic error of the direct linear
/// transform in Hartley-normalised coordinates); `None` with fewer than four pairs or a degenerate set.
pub fn fit_homography(pairs: &[PointPair]) -> Option<Homography> {
    fit_homography_weighted(pairs, &vec![1.0; pairs.len()])
}

/// [`fit_homography`] with a weight per pair (non-negative; pairs of weight 0 left out).
#[allow(clippy::needless_range_loop)] // the normal equations, indexed as written
pub fn fit_homography_weighted(pairs: &[PointPair], weights: &[f64]) -> Option<Homography> {
    let pairs: Vec<(PointPair, f64)> =
        pairs.iter().zip(weights).filter(|(_, w)| **w > 0.0 && w.is_finite()).map(|(p, w)| (*p, *w)).collect();
    if pairs.len() < 4 {
        return None;
    }
    // Similarity that moves the points' centroid to 0 and their mean distance to sqrt(2).
    let norm = |pts: &mut dyn Iterator<Item = (f64, f64)>| -> Option<Homography> {
        let v: Vec<(f64, f64)> = pts.collect();
        let n = v.len() as f64;
        let (mx, my) = (v.iter().map(|p| p.0).sum::<f64>() / n, v.iter().map(|p| p.1).sum::<f64>() / n);
        let d = v.iter().map(|p| (p.0 - mx).hypot(p.1 - my)).sum::<f64>() / n;
        (d > 1e-12 && d.is_finite()).then(|| {
            let s = std::f64::consts::SQRT_2 / d;
            Homography([s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0])
        })
    };
    let ts = norm(&mut pairs.iter().map(|p| p.0 .0))?;
    let td = norm(&mut pairs.iter().map(|p| p.0 .1))?;
    let mut a = [[0.0f64; 8]; 8];
    let mut b = [0.0f64; 8];
    for &((p, q), wt) in &pairs {
        let (x, y) = ts.apply(p.0, p.1);
        let (u, v) = td.apply(q.0, q.1);
        for (row, rhs) in
            [([x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y], u), ([0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y], v)]
        {
            for r in 0..8 {
                b[r] += wt * row[r] * rhs;
                for c in 0..8 {
                    a[r][c] += wt * row[r] * row[c];
                }
            }
        }
    }
    let h = solve8(a, b)?;
    let hn = Homography([h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0]);
    let out = td.inverse()?.mul(&hn).mul(&ts);
    out.0.iter().all(|v| v.is_finite()).then_some(out)
}

use super::plane::Plane;
use super::warp::{ShiftField, Warp};

/// How an alignment ended.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AlignStats {
    /// Correlation of the gradient images over the overlap after alignment.
    pub correlation: f64,
    /// Largest remaining shift on the four quadrants (pixels), by translation-only Lucas-Kanade, after the
    /// homography and the residual field.
    pub residual_px: f64,
    /// The same with the homography alone.
    pub homography_residual_px: f64,
    /// Largest shift of the residual field (pixels): how far the band is from a pure homography.
    pub field_max_px: f64,
    /// Gauss-Newton iterations over all levels.
    pub iterations: usize,
}

struct Level {
    t: Plane,
    i: Plane,
    ix: Plane,
    iy: Plane,
}

pub fn gradient_image(p: &Plane) -> Plane {
    // NaN (outside the source) becomes 0 before differentiating, so borders do not spread NaN.
    let clean = Plane::new(p.width, p.height, p.data.iter().map(|v| if v.is_finite() { *v } else { 0.0 }).collect());
    let mut g = clean.blur().gradient_magnitude();
    for (o, v) in g.data.iter_mut().zip(&p.data) {
        if !v.is_finite() {
            *o = f32::NAN;
        }
    }
    g
}

fn pyramid(template: &Plane, image: &Plane, levels: usize) -> Vec<Level> {
    let mut out = Vec::new();
    let (mut t, mut i) = (template.clone(), image.clone());
    for l in 0..levels {
        let (tg, ig) = (gradient_image(&t), gradient_image(&i));
        let (ix, iy) = ig.gradients();
        out.push(Level { t: tg, i: ig, ix, iy });
        if l + 1 < levels {
            t = t.downsample();
            i = i.downsample();
        }
    }
    out
}

/// Solves `a x = b` (8x8, Gaussian elimination with partial pivoting).
#[allow(clippy::needless_range_loop)] // dense linear algebra reads clearer with row/column indices
fn solve8(mut a: [[f64; 8]; 8], mut b: [f64; 8]) -> Option<[f64; 8]> {
    for c in 0..8 {
        let p = (c..8).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-30 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..8 {
            let f = a[r][c] / a[c][c];
            for k in c..8 {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 8];
    for c in (0..8).rev() {
        let s: f64 = (c + 1..8).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    Some(x)
}

/// Normalised cross-correlation of t(u) and i(u + d) over the overlap.
fn ncc_shift(t: &Plane, i: &Plane, dx: isize, dy: isize) -> f64 {
    let (mut n, mut st, mut si, mut stt, mut sii, mut sti) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for y in 0..t.height as isize {
        let yi = y + dy;
        if yi < 0 || yi >= i.height as isize {
            continue;
        }
        for x in 0..t.width as isize {
            let xi = x + dx;
            if xi < 0 || xi >= i.width as isize {
                continue;
            }
            let (a, b) = (t.at(x as usize, y as usize) as f64, i.at(xi as usize, yi as usize) as f64);
            if !a.is_finite() || !b.is_finite() {
                continue;
            }
            n += 1.0;
            st += a;
            si += b;
            stt += a * a;
            sii += b * b;
            sti += a * b;
        }
    }
    if n < 16.0 {
        return -1.0;
    }
    let cov = sti - st * si / n;
    let den = ((stt - st * st / n) * (sii - si * si / n)).sqrt();
    if den > 0.0 {
        cov / den
    } else {
        -1.0
    }
}

#[allow(clippy::needless_range_loop)] // the normal equations, indexed as written
/// One level of Gauss-Newton on the 8 parameters (normalised coordinates). Returns (H, iterations, correlation).
fn refine_level(lv: &Level, h: Homography, max_iter: usize, stride: usize, tol_px: f64) -> (Homography, usize, f64) {
    let (w, hh) = (lv.t.width, lv.t.height);
    let s = 0.5 * w.max(hh) as f64;
    let (cx, cy) = (0.5 * (w as f64 - 1.0), 0.5 * (hh as f64 - 1.0));
    // Pixel <-> normalised: n = (p - c) / s.
    let to_n = Homography([1.0 / s, 0.0, -cx / s, 0.0, 1.0 / s, -cy / s, 0.0, 0.0, 1.0]);
    let from_n = to_n.inverse().expect("scaling");
    let mut hn = to_n.mul(&h).mul(&from_n);
    let mut iters = 0;
    let mut corr = 0.0;
    let mut samples: Vec<(f64, f64, f64, f64, f64, f64)> = Vec::new();
    for _ in 0..max_iter {
        iters += 1;
        samples.clear();
        let hp = from_n.mul(&hn).mul(&to_n);
        for y in (0..hh).step_by(stride) {
            for x in (0..w).step_by(stride) {
                let tv = lv.t.at(x, y);
                if !tv.is_finite() {
                    continue;
                }
                let (u, v) = hp.apply(x as f64, y as f64);
                let (Some(iv), Some(gx), Some(gy)) = (lv.i.sample(u, v), lv.ix.sample(u, v), lv.iy.sample(u, v)) else {
                    continue;
                };
                let (xn, yn) = ((x as f64 - cx) / s, (y as f64 - cy) / s);
                samples.push((xn, yn, tv as f64, iv as f64, gx as f64 * s, gy as f64 * s));
            }
        }
        let n = samples.len() as f64;
        if n < 64.0 {
            break;
        }
        // Photometric gain and offset: least squares of alpha * I + beta ~ T.
        let (mut si, mut st, mut sii, mut sit, mut stt) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(_, _, t, i, _, _) in &samples {
            si += i;
            st += t;
            sii += i * i;
            sit += i * t;
            stt += t * t;
        }
        let var_i = sii - si * si / n;
        let var_t = stt - st * st / n;
        if var_i <= 0.0 || var_t <= 0.0 {
            break;
        }
        let alpha = (sit - si * st / n) / var_i;
        let beta = (st - alpha * si) / n;
        corr = (sit - si * st / n) / (var_i * var_t).sqrt();
        let mut a = [[0.0f64; 8]; 8];
        let mut g = [0.0f64; 8];
        let hv = hn.0;
        for &(xn, yn, t, i, gx, gy) in &samples {
            let d = hv[6] * xn + hv[7] * yn + hv[8];
            let xp = (hv[0] * xn + hv[1] * yn + hv[2]) / d;
            let yp = (hv[3] * xn + hv[4] * yn + hv[5]) / d;
            let (ax, ay) = (alpha * gx, alpha * gy);
            let j = [
                ax * xn / d,
                ax * yn / d,
                ax / d,
                ay * xn / d,
                ay * yn / d,
                ay / d,
                -(ax * xp + ay * yp) * xn / d,
                -(ax * xp + ay * yp) * yn / d,
            ];
            let e = alpha * i + beta - t;
            for r in 0..8 {
                g[r] += j[r] * e;
                for c in r..8 {
                    a[r][c] += j[r] * j[c];
                }
            }
        }
        for r in 0..8 {
            for c in 0..r {
                a[r][c] = a[c][r];
            }
            a[r][r] *= 1.0 + 1e-6;
        }
        let Some(delta) = solve8(a, g.map(|v| -v)) else { break };
        let mut nv = hn.0;
        for k in 0..8 {
            nv[k] += delta[k];
        }
        let next = Homography(nv).normalized();
        // Largest movement of the image corners, in pixels of this level.
        let moved = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .iter()
            .map(|&(x, y)| {
                let (a, b) = hn.apply(x, y);
                let (c, d) = next.apply(x, y);
                (a - c).hypot(b - d) * s
            })
            .fold(0.0, f64::max);
        hn = next;
        if moved < tol_px {
            break;
        }
    }
    (from_n.mul(&hn).mul(&to_n), iters, corr)
}

/// Aligns `image` to `template` (both already in the target camera), starting from `init` (template pixel ->
/// image pixel). Returns the refined homography with its residual shift field.
pub fn align(template: &Plane, image: &Plane, init: Homography) -> (Warp, AlignStats) {
    let levels = 4usize.min(((template.width.min(template.height) as f64 / 32.0).log2().floor() as usize).max(1));
    let pyr = pyramid(template, image, levels);
    let top = levels - 1;
    // Pixel centres at integers: a coarse pixel x covers fine pixels 2x..2x+1, centre 2x + 0.5.
    let to_level = |h: &Homography, l: usize| -> Homography {
        let f = 2f64.powi(l as i32);
        let off = 0.5 * (f - 1.0);
        let s = Homography([f, 0.0, off, 0.0, f, off, 0.0, 0.0, 1.0]); // level -> full
        s.inverse().expect("scale").mul(h).mul(&s)
    };
    let from_level = |h: &Homography, l: usize| -> Homography {
        let f = 2f64.powi(l as i32);
        let off = 0.5 * (f - 1.0);
        let s = Homography([f, 0.0, off, 0.0, f, off, 0.0, 0.0, 1.0]);
        s.mul(h).mul(&s.inverse().expect("scale"))
    };
    // Coarse translation search on top of the rig guess.
    let top_lv = &pyr[top];
    let warped_top =
        warp_plane(&top_lv.i, &Warp::from_homography(to_level(&init, top)), top_lv.t.width, top_lv.t.height);
    // Periodic scenes (crop rows) correlate at several shifts: among the shifts within 0.02 of the best
    // correlation, the one nearest the rig's guess wins.
    let mut scores = Vec::with_capacity(625);
    for dy in -12isize..=12 {
        for dx in -12isize..=12 {
            scores.push((ncc_shift(&top_lv.t, &warped_top, dx, dy), dx, dy));
        }
    }
    let top_score = scores.iter().map(|s| s.0).fold(f64::NEG_INFINITY, f64::max);
    let best = scores
        .iter()
        .filter(|s| s.0 >= top_score - 0.02)
        .min_by_key(|s| s.1 * s.1 + s.2 * s.2)
        .copied()
        .unwrap_or((0.0, 0, 0));
    let mut h_level = Homography::translation(best.1 as f64, best.2 as f64);
    h_level = to_level(&init, top).mul(&h_level);
    let mut iterations = 0;
    let mut corr = 0.0;
    for l in (0..levels).rev() {
        let lv = &pyr[l];
        // Finer levels only polish what the coarser ones found: fewer iterations, on every second pixel; coarse
        // levels stop at 0.01 px of corner movement (the next level refines), the finest at 0.002 px.
        let (max_iter, stride, tol) = match l {
            0 => (10, 2, 0.002),
            1 => (20, 2, 0.01),
            _ => (30, 1, 0.01),
        };
        let (h, it, c) = refine_level(lv, h_level, max_iter, stride, tol);
        iterations += it;
        corr = c;
        if l > 0 {
            h_level = to_level(&from_level(&h, l), l - 1);
        } else {
            h_level = h;
        }
    }
    let homography_residual_px = residual_shift(&pyr[0].t, &pyr[0].i, &Warp::from_homography(h_level));
    let field = fit_field(&pyr[0].t, &pyr[0].i, &h_level);
    let field_max_px = field.max_norm();
    let warp = Warp { homography: h_level, field: Some(field) };
    let residual_px = residual_shift(&pyr[0].t, &pyr[0].i, &warp);
    (warp, AlignStats { correlation: corr, residual_px, homography_residual_px, field_max_px, iterations })
}

/// Resamples `src` through `warp` (out pixel -> src pixel) into a `w` x `h` plane.
pub fn warp_plane(src: &Plane, warp: &Warp, w: usize, h: usize) -> Plane {
    let mut out = vec![f32::NAN; w * h];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = warp.apply(x as f64, y as f64);
            if let Some(s) = src.sample(u, v) {
                out[y * w + x] = s;
            }
        }
    }
    Plane::new(w, h, out)
}

/// Translation-only Lucas-Kanade with gain and offset in the window [x0, x1) x [y0, y1): the shift e with
/// `warped(x + e) ~ alpha * t(x) + beta`. Returns the shift and the smaller eigenvalue of the structure tensor
/// per pixel (how well the window constrains it), or `None` without enough valid pixels.
pub fn local_shift(
    t: &Plane,
    warped: &Plane,
    grads: &(Plane, Plane),
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    stride: usize,
) -> Option<((f64, f64), f64)> {
    let (gx, gy) = grads;
    let mut d = (0.0f64, 0.0f64);
    let mut strength = 0.0;
    let mut pts = Vec::new();
    for _ in 0..6 {
        pts.clear();
        for y in (y0..y1).step_by(stride) {
            for x in (x0..x1).step_by(stride) {
                let tv = t.at(x, y);
                let (xs, ys) = (x as f64 + d.0, y as f64 + d.1);
                let (Some(v), Some(ex), Some(ey)) = (warped.sample(xs, ys), gx.sample(xs, ys), gy.sample(xs, ys))
                else {
                    continue;
                };
                if tv.is_finite() && ex.is_finite() && ey.is_finite() {
                    pts.push((tv as f64, v as f64, ex as f64, ey as f64));
                }
            }
        }
        let n = pts.len() as f64;
        if n < 50.0 {
            return None;
        }
        let (mt, mv) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        let cov: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1 - mv)).sum();
        let var: f64 = pts.iter().map(|p| (p.1 - mv).powi(2)).sum();
        if var <= 0.0 || cov <= 0.0 {
            return None;
        }
        let alpha = cov / var;
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(tv, v, ex, ey) in &pts {
            let e = alpha * (v - mv) - (tv - mt);
            let (jx, jy) = (alpha * ex, alpha * ey);
            a11 += jx * jx;
            a12 += jx * jy;
            a22 += jy * jy;
            b1 += jx * e;
            b2 += jy * e;
        }
        let det = a11 * a22 - a12 * a12;
        if det.abs() < 1e-30 {
            return None;
        }
        let tr = a11 + a22;
        strength = (0.5 * (tr - (tr * tr - 4.0 * det).max(0.0).sqrt())) / n;
        let step = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det);
        d.0 -= step.0;
        d.1 -= step.1;
        if d.0.hypot(d.1) > 8.0 {
            return None;
        }
        if step.0.hypot(step.1) < 1e-3 {
            break;
        }
    }
    Some((d, strength))
}

/// Median of a list (NaN-free).
/// The upper median, 0 for no values (no shift).
fn median(v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    crate::util::stats::upper_median(&v)
}

/// Node spacing of the residual shift field, in target pixels.
pub const FIELD_STEP: f64 = 128.0;

/// Fits the residual shift field on top of `h` (two passes; see [`super::warp`]).
pub fn fit_field(t: &Plane, i: &Plane, h: &Homography) -> ShiftField {
    let (w, hh) = (t.width, t.height);
    let mut field = ShiftField::zeros(w, hh, FIELD_STEP);
    let half = FIELD_STEP as usize;
    for _pass in 0..2 {
        let warp = Warp { homography: *h, field: Some(field.clone()) };
        let warped = warp_plane(i, &warp, w, hh);
        let grads = warped.gradients();
        let mut found: Vec<Option<((f64, f64), f64)>> = Vec::with_capacity(field.d.len());
        for j in 0..field.ny {
            for k in 0..field.nx {
                let (cx, cy) = field.node(k, j);
                let (cx, cy) = (cx as usize, cy as usize);
                let win = (cx.saturating_sub(half), cy.saturating_sub(half), (cx + half).min(w), (cy + half).min(hh));
                found.push(local_shift(t, &warped, &grads, win, 2));
            }
        }
        let strong = median(found.iter().flatten().map(|(_, s)| *s).collect());
        let ok: Vec<Option<[f64; 2]>> =
            found.iter().map(|f| f.and_then(|((dx, dy), s)| (s > 0.05 * strong).then_some([dx, dy]))).collect();
        // Fill weak nodes, then a 3x3 median per component.
        let (nx, ny) = (field.nx, field.ny);
        let global = [0, 1].map(|c| median(ok.iter().flatten().map(|v| v[c]).collect()));
        let filled: Vec<[f64; 2]> = (0..nx * ny)
            .map(|n| {
                ok[n].unwrap_or_else(|| {
                    let (k, j) = (n % nx, n / nx);
                    let neigh: Vec<[f64; 2]> = (j.saturating_sub(1)..(j + 2).min(ny))
                        .flat_map(|jj| (k.saturating_sub(1)..(k + 2).min(nx)).map(move |kk| jj * nx + kk))
                        .filter_map(|m| ok[m])
                        .collect();
                    if neigh.is_empty() {
                        global
                    } else {
                        [0, 1].map(|c| median(neigh.iter().map(|v| v[c]).collect()))
                    }
                })
            })
            .collect();
        for n in 0..nx * ny {
            let (k, j) = (n % nx, n / nx);
            let neigh: Vec<[f64; 2]> = (j.saturating_sub(1)..(j + 2).min(ny))
                .flat_map(|jj| (k.saturating_sub(1)..(k + 2).min(nx)).map(move |kk| jj * nx + kk))
                .map(|m| filled[m])
                .collect();
            for c in 0..2 {
                field.d[n][c] += median(neigh.iter().map(|v| v[c]).collect());
            }
        }
    }
    field
}

/// Largest translation left between `t` and `i` warped by `warp`, by the local Lucas-Kanade of
/// [`local_shift`] on the four image quadrants.
pub fn residual_shift(t: &Plane, i: &Plane, warp: &Warp) -> f64 {
    let warped = warp_plane(i, warp, t.width, t.height);
    let grads = warped.gradients();
    let (w, hh) = (t.width, t.height);
    let mut worst = 0.0f64;
    for q in 0..4 {
        let (x0, y0) = ((q % 2) * w / 2, (q / 2) * hh / 2);
        if let Some(((dx, dy), _)) =
            local_shift(t, &warped, &grads, (x0 + 2, y0 + 2, x0 + w / 2 - 2, y0 + hh / 2 - 2), 1)
        {
            worst = worst.max(dx.hypot(dy));
        }
    }
    worst
}
