//! Band-to-band registration: a homography per band mapping the reference band's target pixels to the band's
//! (undistorted, target-camera) pixels, with a residual shift field where the images call for one.
//!
//! **What is compared: contrast-invariant structure.** Bands do not share intensities: vegetation is dark in the
//! visible bands and bright in the NIR, a gravel track the other way round, so an edge between them flips its sign
//! from band to band, and its strength varies with the materials' spectra. Each image is turned into its doubled-
//! angle gradient orientation field ([`structure`]): with g the gradient of the blurred image,
//! `(gx^2 - gy^2, 2 gx gy) / (|g|^2 + eps^2)`. Squaring the gradient as a complex number doubles its angle, so g and
//! -g give the same vector (invariant to the contrast's sign); dividing by `|g|^2` makes it a unit vector wherever
//! the gradient stands above the noise (invariant to the contrast's magnitude), while `eps^2`, a multiple of the
//! `|g|^2` the image's own pixel noise gives ([`noise_sigma`]), fades flat, noisy areas out. The inner product of
//! two such fields is `|n_T|^2 |n_I|^2 cos(2 dtheta)`, the normalised-gradient-field similarity (Haber and
//! Modersitzki) in a form least squares can use. Gradient magnitudes keep the sign invariance but not the
//! magnitude's: a strong material edge outweighs the texture around it, and an edge that one band barely shows
//! pulls the fit; intensities (ECC on raw images) are defeated by the inverted contrast.
//!
//! - **Initial guess** from the rig: `H = K_t R_rel K_t^-1` from `Camera:RigRelatives` (rotation only, exact at
//!   infinity: MicaSense's `get_homography`), plus DJI's `RelativeOpticalCenter` shift; identity when the files
//!   carry neither. Then a coarse translation search (cosine similarity of the orientation fields over +-12 pixels
//!   of the coarsest level) takes up whatever the rig data missed.
//! - **Refinement**: Gauss-Newton on the 8 homography parameters over a pyramid, minimising
//!   `sum_u sum_c (alpha I_c(H u) - T_c(u))^2` over the two orientation channels with the gain alpha refitted every
//!   iteration (ECC's correlation for a gain-only model), in coordinates normalised to [-1, 1] so the perspective
//!   terms stay well conditioned. It stops at the working level: the finest whose structure stands above the
//!   sensor's noise ([`STRUCTURE_MIN_ENERGY`]). A real scene's fine texture is worth full resolution; where the
//!   finest levels hold mostly noise, aligning on them is biased (towards whole-pixel shifts) in a way no scatter
//!   shows, and coarser levels, whose box filter averages the noise down, do better.
//! - **Model choice**: a calibrated rig's guess is wrong by the parallax of the ground between band cameras a few
//!   centimetres apart, which for a distant plane is a translation; where the files carry no rotation (DJI's
//!   relative optical centres) a small rotation of the band camera is missing too. Three models compete
//!   ([`AlignModel`]: translation, rigid = translation and rotation, full homography) by the Bayesian information
//!   criterion over the translations left in tiles of the working level, each weighted by its information: the
//!   parameters a model adds must explain more than the tiles' noise. Real rigs whose lens or rig calibration is
//!   off get the homography, a calibrated rig the translation, whose estimate the six other parameters would only
//!   make noisier.
//! - **Robustness to relief**: roofs and crowns stand metres above the ground and their parallax differs from the
//!   ground's; the translation is re-estimated from the tiles by iteratively reweighted least squares with Tukey's
//!   biweight, so it follows the image's majority rather than averaging the strongest (roof) edges in.
//! - **Residual field**: a smooth polynomial shift field on top of the homography ([`super::warp`]), fitted to
//!   per-node translations and kept only when the Bayesian information criterion prefers it to none (lens-model
//!   errors are smooth over the image; the nodes' noise is not).
//! - **Residual**: after alignment a translation-only Lucas-Kanade on each image quadrant measures the shift that
//!   is left; the largest is reported per band, with and without the field.
//!
//! Pixel centres are at integer coordinates at every level (a level pixel p is the full-resolution point
//! `2^l p + (2^l - 1) / 2`); shifts and residuals are reported in full-resolution target pixels.

use super::plane::Plane;
use super::warp::{ShiftField, Warp};
use crate::maths::linear::solve;

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

/// The homography's freedom on top of the initial guess ([`align`] chooses). In coordinates normalised to
/// [-1, 1] a small rotation of the band camera, `K R K^-1`, moves `h[2]`, `h[5]` (translation), `h[1] = -h[3]`
/// (rotation about the optical axis) and `h[6]`, `h[7]` (the perspective that turning about x and y adds).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AlignModel {
    /// The guess (the rig's rotation homography) followed by a translation: what the parallax of a distant plane
    /// adds to a calibrated rig (2 parameters).
    Translation,
    /// A translation and a small rotation of the band camera: what a rig whose files carry no rotation (DJI's
    /// relative optical centres), or a slightly wrong one, needs besides the parallax (5 parameters).
    Rigid,
    /// All eight parameters (lens or rig calibrations that disagree in scale or shear).
    Homography,
}

impl AlignModel {
    /// The parameter updates the model allows, as columns over the 8 entries `h[0..8]` (normalised coordinates).
    fn basis(self) -> Vec<[f64; 8]> {
        let unit = |k: usize| std::array::from_fn(|i| if i == k { 1.0 } else { 0.0 });
        match self {
            AlignModel::Translation => vec![unit(2), unit(5)],
            AlignModel::Rigid => {
                vec![unit(2), unit(5), [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], unit(6), unit(7)]
            }
            AlignModel::Homography => (0..8).map(unit).collect(),
        }
    }
}

/// How an alignment ended.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AlignStats {
    /// The model the images supported (Bayesian information criterion over the tiles' residual shifts).
    pub model: AlignModel,
    /// Correlation of the two images' orientation fields ([`structure`]) over the overlap after alignment.
    pub correlation: f64,
    /// Largest remaining shift on the four quadrants (pixels), by translation-only Lucas-Kanade on the
    /// orientation fields, after the homography and the residual field.
    pub residual_px: f64,
    /// The same with the homography alone.
    pub homography_residual_px: f64,
    /// Largest shift of the residual field (pixels): how far the band is from a pure homography (0 without one).
    pub field_max_px: f64,
    /// Gauss-Newton iterations over all levels.
    pub iterations: usize,
}

impl AlignStats {
    /// No alignment could be made (the guess is kept).
    fn failed(iterations: usize) -> AlignStats {
        AlignStats {
            model: AlignModel::Homography,
            correlation: 0.0,
            residual_px: 0.0,
            homography_residual_px: 0.0,
            field_max_px: 0.0,
            iterations,
        }
    }
}

/// Gradient magnitude of a blurred copy (NaN where the plane has none).
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

/// Robust standard deviation of a plane's pixel noise: the median absolute 2x2 diagonal difference
/// `(a - b - c + d) / 2` (blind to constant and linear trends) over blocks with four values, times 1.4826.
pub fn noise_sigma(p: &Plane) -> f32 {
    let (w, h) = (p.width, p.height);
    let mut v = Vec::with_capacity((w / 2) * (h / 2));
    for y in (0..h.saturating_sub(1)).step_by(2) {
        for x in (0..w.saturating_sub(1)).step_by(2) {
            let k = y * w + x;
            let d = 0.5 * (p.data[k] - p.data[k + 1] - p.data[k + w] + p.data[k + w + 1]);
            if d.is_finite() {
                v.push(d.abs());
            }
        }
    }
    if v.is_empty() {
        return 0.0;
    }
    let m = v.len() / 2;
    let (_, med, _) = v.select_nth_unstable_by(m, f32::total_cmp);
    1.4826 * *med
}

/// Binomial blur passes ([`Plane::blur`]) before the gradient of [`structure`].
pub const STRUCTURE_BLUR: usize = 4;

/// `eps^2` of [`structure`] in units of the mean `|g|^2` that the image's pixel noise alone gives.
pub const STRUCTURE_NOISE_EPS: f64 = 4.0;

/// Sums of squares of the 1D kernels: the binomial blur `n` times, and the same followed by a central difference.
fn kernel_gains(n: usize) -> (f64, f64) {
    let mut b = vec![1.0f64];
    for _ in 0..n {
        let mut nb = vec![0.0; b.len() + 2];
        for (k, v) in b.iter().enumerate() {
            nb[k] += 0.25 * v;
            nb[k + 1] += 0.5 * v;
            nb[k + 2] += 0.25 * v;
        }
        b = nb;
    }
    let mut d = vec![0.0; b.len() + 2];
    for (k, v) in b.iter().enumerate() {
        d[k] -= 0.5 * v;
        d[k + 2] += 0.5 * v;
    }
    (b.iter().map(|v| v * v).sum(), d.iter().map(|v| v * v).sum())
}

/// Erodes a validity mask by `r` pixels: a pixel stays valid when every pixel within `r` in x and in y is.
fn erode(valid: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let pass = |src: &[bool], n: usize, lines: usize, at: &dyn Fn(usize, usize) -> usize| -> Vec<bool> {
        let mut out = vec![false; src.len()];
        let mut pre = vec![0usize; n + 1];
        for line in 0..lines {
            for k in 0..n {
                pre[k + 1] = pre[k] + src[at(line, k)] as usize;
            }
            for k in 0..n {
                let (a, b) = (k.saturating_sub(r), (k + r + 1).min(n));
                out[at(line, k)] = pre[b] - pre[a] == b - a;
            }
        }
        out
    };
    let rows = pass(valid, w, h, &|y, x| y * w + x);
    pass(&rows, h, w, &|x, y| y * w + x)
}

/// An image's contrast-invariant structure ([`structure`]).
pub struct Structure {
    /// The doubled-angle orientation field's two channels (NaN where undefined).
    pub channels: [Plane; 2],
    /// The mean of `|g|^2 / (|g|^2 + eps^2)` over the pixels with a value: the share of the image whose structure
    /// stands above its noise (1 all structure, near 0 all noise).
    pub energy: f64,
}

/// The two channels of an image's contrast-invariant structure (see the module doc): with g the gradient of the
/// blurred image ([`STRUCTURE_BLUR`]) and `eps^2` a multiple ([`STRUCTURE_NOISE_EPS`]) of the `|g|^2` its pixel
/// noise alone gives, `(gx^2 - gy^2, 2 gx gy) / (|g|^2 + eps^2)`. NaN where the blur and the difference reach a
/// pixel without a value.
pub fn structure(p: &Plane) -> Structure {
    let (w, h) = (p.width, p.height);
    let finite: Vec<bool> = p.data.iter().map(|v| v.is_finite()).collect();
    let valid = erode(&finite, w, h, STRUCTURE_BLUR + 1);
    let mut blurred = Plane::new(w, h, p.data.iter().map(|v| if v.is_finite() { *v } else { 0.0 }).collect());
    for _ in 0..STRUCTURE_BLUR {
        blurred = blurred.blur();
    }
    let (gx, gy) = blurred.gradients();
    let (sb, sd) = kernel_gains(STRUCTURE_BLUR);
    let sigma = noise_sigma(p) as f64;
    let eps2 = STRUCTURE_NOISE_EPS * 2.0 * sigma * sigma * sb * sd;
    let g2: Vec<f64> = gx.data.iter().zip(&gy.data).map(|(a, b)| (a * a + b * b) as f64).collect();
    let n = valid.iter().filter(|v| **v).count();
    // A noise-free image (a synthetic one) still needs a floor: a tiny share of its mean |g|^2.
    let mean_g2 = g2.iter().zip(&valid).filter(|(_, v)| **v).map(|(g, _)| g).sum::<f64>() / n.max(1) as f64;
    let eps2 = eps2.max(1e-4 * mean_g2).max(f32::MIN_POSITIVE as f64);
    let mut c0 = vec![f32::NAN; w * h];
    let mut c1 = vec![f32::NAN; w * h];
    let mut energy = 0.0f64;
    for i in 0..w * h {
        if valid[i] {
            let (a, b) = (gx.data[i] as f64, gy.data[i] as f64);
            let d = g2[i] + eps2;
            c0[i] = ((a * a - b * b) / d) as f32;
            c1[i] = (2.0 * a * b / d) as f32;
            energy += g2[i] / d;
        }
    }
    Structure { channels: [Plane::new(w, h, c0), Plane::new(w, h, c1)], energy: energy / n.max(1) as f64 }
}

/// The structure energy ([`Structure::energy`]) a level needs, template and image averaged, to be aligned on. A
/// level whose structure is mostly the sensor's noise biases the alignment (interpolating a noisy image smooths its
/// noise by an amount that depends on the sub-pixel shift, a known pull towards whole-pixel shifts); a scene's fine
/// texture, where there is some, is worth the finer level's cost.
pub const STRUCTURE_MIN_ENERGY: f64 = 0.65;

/// One pyramid level: the template's and the image's orientation fields, the image's field gradients and the
/// level's scale (a level pixel p is the full-resolution point `f p + (f - 1) / 2`, f = 2^level).
struct Level {
    t: [Plane; 2],
    i: [Plane; 2],
    /// The template's and the image's structure energy, averaged.
    energy: f64,
    /// Per pixel, interleaved for one lookup: the image's two channels and their d/dx, d/dy
    /// (`[c0, c1, dc0/dx, dc0/dy, dc1/dx, dc1/dy]`).
    img: Vec<[f32; 6]>,
    f: f64,
}

impl Level {
    fn new(template: &Plane, image: &Plane, level: usize) -> Level {
        let (st, si) = (structure(template), structure(image));
        let energy = 0.5 * (st.energy + si.energy);
        let (t, i) = (st.channels, si.channels);
        let ((gx0, gy0), (gx1, gy1)) = (i[0].gradients(), i[1].gradients());
        let img = (0..i[0].data.len())
            .map(|k| [i[0].data[k], i[1].data[k], gx0.data[k], gy0.data[k], gx1.data[k], gy1.data[k]])
            .collect();
        Level { t, i, energy, img, f: 2f64.powi(level as i32) }
    }

    /// The image's channels and their gradients at (u, v) (bilinear, level pixels); `None` outside or next to a
    /// pixel without a value.
    #[inline]
    fn sample(&self, u: f64, v: f64) -> Option<[f32; 6]> {
        let (w, h) = (self.width(), self.height());
        if w < 2 || h < 2 || !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
            return None;
        }
        // Non-negative here: truncation is the floor.
        let (x0, y0) = ((u as usize).min(w - 2), (v as usize).min(h - 2));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let k = y0 * w + x0;
        let (a, b, c, d) = (&self.img[k], &self.img[k + 1], &self.img[k + w], &self.img[k + w + 1]);
        let (wa, wb, wc, wd) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let mut out = [0.0f32; 6];
        let mut sum = 0.0f32;
        for q in 0..6 {
            out[q] = a[q] * wa + b[q] * wb + c[q] * wc + d[q] * wd;
            sum += out[q];
        }
        sum.is_finite().then_some(out)
    }

    fn width(&self) -> usize {
        self.t[0].width
    }

    fn height(&self) -> usize {
        self.t[0].height
    }

    /// Level pixel -> full-resolution pixel.
    fn up(&self, p: f64) -> f64 {
        self.f * p + 0.5 * (self.f - 1.0)
    }

    /// Full-resolution pixel -> level pixel.
    fn down(&self, x: f64) -> f64 {
        (x - 0.5 * (self.f - 1.0)) / self.f
    }

    /// A full-resolution homography in this level's pixels.
    fn homography(&self, h: &Homography) -> Homography {
        let (f, off) = (self.f, 0.5 * (self.f - 1.0));
        let up = Homography([f, 0.0, off, 0.0, f, off, 0.0, 0.0, 1.0]);
        let down = Homography([1.0 / f, 0.0, -off / f, 0.0, 1.0 / f, -off / f, 0.0, 0.0, 1.0]);
        down.mul(h).mul(&up)
    }

    /// A homography in this level's pixels at full resolution.
    fn full(&self, h: &Homography) -> Homography {
        let (f, off) = (self.f, 0.5 * (self.f - 1.0));
        let up = Homography([f, 0.0, off, 0.0, f, off, 0.0, 0.0, 1.0]);
        let down = Homography([1.0 / f, 0.0, -off / f, 0.0, 1.0 / f, -off / f, 0.0, 0.0, 1.0]);
        up.mul(h).mul(&down)
    }
}

/// Solves `a x = b` (8x8).
fn solve8(a: [[f64; 8]; 8], b: [f64; 8]) -> Option<[f64; 8]> {
    let x = solve(a.iter().flatten().copied().collect(), b.to_vec())?;
    Some(std::array::from_fn(|k| x[k]))
}

/// Cosine similarity of two orientation fields with `i` shifted by (dx, dy): `sum t . i(u + d)` over the overlap,
/// normalised by both fields' energy there; -1 with too small an overlap.
fn structure_similarity(t: &[Plane; 2], i: &[Plane; 2], dx: isize, dy: isize) -> f64 {
    let (w, h) = (t[0].width as isize, t[0].height as isize);
    let iw = i[0].width as isize;
    let (mut n, mut tt, mut ii, mut ti) = (0usize, 0.0f64, 0.0f64, 0.0f64);
    for y in 0.max(-dy)..h.min(i[0].height as isize - dy) {
        for x in 0.max(-dx)..w.min(iw - dx) {
            let a = (y * w + x) as usize;
            let b = ((y + dy) * iw + x + dx) as usize;
            let (t0, t1, i0, i1) = (t[0].data[a], t[1].data[a], i[0].data[b], i[1].data[b]);
            if !(t0.is_finite() && t1.is_finite() && i0.is_finite() && i1.is_finite()) {
                continue;
            }
            n += 1;
            tt += (t0 * t0 + t1 * t1) as f64;
            ii += (i0 * i0 + i1 * i1) as f64;
            ti += (t0 * i0 + t1 * i1) as f64;
        }
    }
    // Shifts that leave less than half the image overlapping are not compared.
    if n < 64 || 2 * n < t[0].data.len() || tt <= 0.0 || ii <= 0.0 {
        return -1.0;
    }
    ti / (tt * ii).sqrt()
}

/// How much less similar than the guess ([`warp_similarity`]) an alignment may end before it counts as failed.
const FAILED_SIMILARITY_DROP: f64 = 0.05;

/// Cosine similarity of the template's orientation field and the image's through `h` (full resolution) at level
/// `lv`, over every second pixel both have; -1 with too few.
fn warp_similarity(lv: &Level, h: &Homography) -> f64 {
    let hl = lv.homography(h);
    let (w, hh) = (lv.width(), lv.height());
    let (mut n, mut tt, mut ii, mut ti) = (0usize, 0.0f64, 0.0f64, 0.0f64);
    for y in (0..hh).step_by(2) {
        for x in (0..w).step_by(2) {
            let k = y * w + x;
            let (t0, t1) = (lv.t[0].data[k] as f64, lv.t[1].data[k] as f64);
            if !(t0.is_finite() && t1.is_finite()) {
                continue;
            }
            let (u, v) = hl.apply(x as f64, y as f64);
            let Some(s) = lv.sample(u, v) else { continue };
            let (i0, i1) = (s[0] as f64, s[1] as f64);
            n += 1;
            tt += t0 * t0 + t1 * t1;
            ii += i0 * i0 + i1 * i1;
            ti += t0 * i0 + t1 * i1;
        }
    }
    if n < 64 || tt <= 0.0 || ii <= 0.0 {
        return -1.0;
    }
    ti / (tt * ii).sqrt()
}

/// Sampling stride that keeps a level's Gauss-Newton near `target` samples.
fn stride_for(w: usize, h: usize, target: usize) -> usize {
    ((w * h) as f64 / target as f64).sqrt().ceil().max(1.0) as usize
}

/// One level of Gauss-Newton on the 8 homography parameters (normalised coordinates), minimising
/// `sum_u sum_c (alpha I_c(H u) - T_c(u))^2` over the orientation channels with the gain alpha refitted every
/// iteration (the correlation ECC maximises, for a gain-only photometric model). `h` and the result are in the
/// level's pixels. Returns (H, iterations, correlation).
#[allow(clippy::needless_range_loop)] // the normal equations, indexed as written
fn refine_level(
    lv: &Level,
    h: Homography,
    model: AlignModel,
    max_iter: usize,
    stride: usize,
    tol_px: f64,
) -> (Homography, usize, f64) {
    let (w, hh) = (lv.width(), lv.height());
    let s = 0.5 * w.max(hh) as f64;
    let (cx, cy) = (0.5 * (w as f64 - 1.0), 0.5 * (hh as f64 - 1.0));
    // Pixel <-> normalised: n = (p - c) / s.
    let to_n = Homography([1.0 / s, 0.0, -cx / s, 0.0, 1.0 / s, -cy / s, 0.0, 0.0, 1.0]);
    let from_n = Homography([s, 0.0, cx, 0.0, s, cy, 0.0, 0.0, 1.0]);
    let mut hn = to_n.mul(&h).mul(&from_n);
    let mut iters = 0;
    let mut corr = 0.0;
    // (xn, yn, [t0, t1, i0, i1], [di0/dx, di0/dy, di1/dx, di1/dy] per normalised unit)
    let mut samples: Vec<(f64, f64, [f64; 4], [f64; 4])> = Vec::new();
    for _ in 0..max_iter {
        iters += 1;
        samples.clear();
        let hp = from_n.mul(&hn).mul(&to_n);
        for y in (0..hh).step_by(stride) {
            for x in (0..w).step_by(stride) {
                let k = y * w + x;
                let (t0, t1) = (lv.t[0].data[k], lv.t[1].data[k]);
                if !(t0.is_finite() && t1.is_finite()) {
                    continue;
                }
                let (u, v) = hp.apply(x as f64, y as f64);
                let Some(vals) = lv.sample(u, v) else { continue };
                let (xn, yn) = ((x as f64 - cx) / s, (y as f64 - cy) / s);
                let g = [vals[2], vals[3], vals[4], vals[5]].map(|v| v as f64 * s);
                samples.push((xn, yn, [t0 as f64, t1 as f64, vals[0] as f64, vals[1] as f64], g));
            }
        }
        if samples.len() < 64 {
            break;
        }
        let (mut ii, mut ti, mut tt) = (0.0, 0.0, 0.0);
        for (_, _, v, _) in &samples {
            ii += v[2] * v[2] + v[3] * v[3];
            ti += v[0] * v[2] + v[1] * v[3];
            tt += v[0] * v[0] + v[1] * v[1];
        }
        if ii <= 0.0 || tt <= 0.0 {
            break;
        }
        let alpha = ti / ii;
        corr = ti / (ii * tt).sqrt();
        let mut a = [[0.0f64; 8]; 8];
        let mut g = [0.0f64; 8];
        let hv = hn.0;
        for &(xn, yn, v, gr) in &samples {
            let d = hv[6] * xn + hv[7] * yn + hv[8];
            let xp = (hv[0] * xn + hv[1] * yn + hv[2]) / d;
            let yp = (hv[3] * xn + hv[4] * yn + hv[5]) / d;
            for c in 0..2 {
                let (ax, ay) = (alpha * gr[2 * c], alpha * gr[2 * c + 1]);
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
                let e = alpha * v[2 + c] - v[c];
                for r in 0..8 {
                    g[r] += j[r] * e;
                    for q in r..8 {
                        a[r][q] += j[r] * j[q];
                    }
                }
            }
        }
        for r in 0..8 {
            for q in 0..r {
                a[r][q] = a[q][r];
            }
            a[r][r] *= 1.0 + 1e-6;
        }
        // The update in the model's own parameters: B^T A B x = -B^T g, then delta = B x.
        let basis = model.basis();
        let k = basis.len();
        let mut ab = vec![0.0f64; k * k];
        let mut gb = vec![0.0f64; k];
        for (r, br) in basis.iter().enumerate() {
            gb[r] = -(0..8).map(|i| br[i] * g[i]).sum::<f64>();
            for (q, bq) in basis.iter().enumerate() {
                ab[r * k + q] = (0..8).map(|i| (0..8).map(|j| br[i] * a[i][j] * bq[j]).sum::<f64>()).sum();
            }
        }
        let Some(x) = solve(ab, gb) else { break };
        let delta: [f64; 8] = std::array::from_fn(|i| basis.iter().zip(&x).map(|(b, xv)| b[i] * xv).sum());
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
        if !moved.is_finite() {
            break;
        }
        hn = next;
        if moved < tol_px {
            break;
        }
    }
    (from_n.mul(&hn).mul(&to_n), iters, corr)
}

/// Samples of one Gauss-Newton iteration at the working level (a stride keeps larger levels near it).
const GN_SAMPLES: usize = 120_000;

/// Aligns `image` to `template` (both already in the target camera), starting from `init` (template pixel ->
/// image pixel). Returns the refined homography with its residual shift field (when one is significant).
pub fn align(template: &Plane, image: &Plane, init: Homography) -> (Warp, AlignStats) {
    let (w, h) = (template.width, template.height);
    // Levels 0 (full resolution) up to the coarsest: at least 64 pixels on its short side, at most three halvings.
    let levels = ((w.min(h) as f64 / 32.0).log2().floor().max(1.0) as usize).min(4);
    let top = levels - 1;
    let mut planes = vec![(template.clone(), image.clone())];
    for _ in 0..top {
        let (t, i) = planes.last().expect("level 0");
        let next = (t.downsample(), i.downsample());
        planes.push(next);
    }
    let mut pyr: Vec<Option<Level>> = (0..=top).map(|_| None).collect();
    // The working level: the finest whose structure stands above the noise ([`STRUCTURE_MIN_ENERGY`]).
    let mut work = top;
    for (l, (t, i)) in planes.iter().enumerate() {
        let lv = Level::new(t, i, l);
        let enough = lv.energy >= STRUCTURE_MIN_ENERGY;
        pyr[l] = Some(lv);
        if enough {
            work = l;
            break;
        }
    }
    let mut level = |l: usize| -> Level { pyr[l].take().unwrap_or_else(|| Level::new(&planes[l].0, &planes[l].1, l)) };
    // Coarse translation search on top of the rig guess, on the orientation fields of the coarsest level.
    let top_lv = level(top);
    let (tw, th) = (top_lv.width(), top_lv.height());
    let init_top = Warp::from_homography(top_lv.homography(&init));
    let warped_top = [warp_plane(&top_lv.i[0], &init_top, tw, th), warp_plane(&top_lv.i[1], &init_top, tw, th)];
    // Periodic scenes (crop rows) correlate at several shifts: among the shifts within 0.02 of the best
    // similarity, the one nearest the rig's guess wins.
    let mut scores = Vec::with_capacity(625);
    for dy in -12isize..=12 {
        for dx in -12isize..=12 {
            scores.push((structure_similarity(&top_lv.t, &warped_top, dx, dy), dx, dy));
        }
    }
    let top_score = scores.iter().map(|s| s.0).fold(f64::NEG_INFINITY, f64::max);
    let best = scores
        .iter()
        .filter(|s| s.0 >= top_score - 0.02)
        .min_by_key(|s| s.1 * s.1 + s.2 * s.2)
        .copied()
        .unwrap_or((0.0, 0, 0));
    let h_start = top_lv.full(&top_lv.homography(&init).mul(&Homography::translation(best.1 as f64, best.2 as f64)));
    // Gauss-Newton from the coarsest level down to the working level, which polishes what the coarser ones found
    // and stops at 0.002 px of corner movement; coarser levels stop at 0.01 px (the next level refines).
    let mut h_full = h_start;
    let mut iterations = 0;
    let mut corr = 0.0;
    let mut current = Some(top_lv);
    let mut lv = None;
    for l in (work..=top).rev() {
        let this = current.take().unwrap_or_else(|| level(l));
        let (max_iter, tol) = if l == work { (15, 0.002) } else { (30, 0.01) };
        let stride = stride_for(this.width(), this.height(), GN_SAMPLES);
        let (hl, it, c) = refine_level(&this, this.homography(&h_full), AlignModel::Homography, max_iter, stride, tol);
        iterations += it;
        corr = c;
        h_full = this.full(&hl);
        lv = Some(this);
    }
    let Some(lv) = lv else {
        return (Warp::from_homography(init), AlignStats::failed(iterations));
    };
    let lv = &lv;
    // The smaller models: the start moved so that the image centre lands where the homography puts it, then
    // refined at the working level.
    let (ccx, ccy) = (0.5 * (w as f64 - 1.0), 0.5 * (h as f64 - 1.0));
    let ((a, b), (a0, b0)) = (h_full.apply(ccx, ccy), h_start.apply(ccx, ccy));
    let small_start = Homography::translation(a - a0, b - b0).mul(&h_start);
    let stride = stride_for(lv.width(), lv.height(), GN_SAMPLES);
    let mut candidates = vec![(AlignModel::Homography, h_full, corr)];
    for model in [AlignModel::Translation, AlignModel::Rigid] {
        let (hl, it, c) = refine_level(lv, lv.homography(&small_start), model, 15, stride, 0.002);
        iterations += it;
        candidates.push((model, lv.full(&hl), c));
    }
    let (model, h_model, c) = choose_model(lv, &candidates);
    corr = c;
    // A safety net: an alignment that ends clearly less similar than the rig's guess itself has failed (too little
    // structure, a wrong coarse peak); the guess is kept.
    let guess_corr = warp_similarity(lv, &init);
    let model_corr = warp_similarity(lv, &h_model);
    if model_corr.is_nan() || model_corr < guess_corr - FAILED_SIMILARITY_DROP {
        let mut stats = AlignStats::failed(iterations);
        stats.correlation = guess_corr;
        return (Warp::from_homography(init), stats);
    }
    // A translation (the rig's own geometry kept) follows the image's majority.
    let h_full = if model == AlignModel::Translation { robust_translation(lv, h_model) } else { h_model };
    let plain = Warp::from_homography(h_full);
    let homography_residual_px = quadrant_residual(lv, &plain);
    let warp = match fit_field(lv, &h_full, w, h) {
        Some(field) => Warp { homography: h_full, field: Some(field) },
        None => plain,
    };
    let field_max_px = warp.field.as_ref().map_or(0.0, |f| f.max_norm());
    let residual_px = if warp.field.is_some() { quadrant_residual(lv, &warp) } else { homography_residual_px };
    (warp, AlignStats { model, correlation: corr, residual_px, homography_residual_px, field_max_px, iterations })
}

/// Tukey's biweight cut-off of [`robust_translation`], in robust standard deviations of the tiles' residuals.
const ROBUST_TUKEY: f64 = 4.0;

/// The translations left in tiles of the working level (tiles of [`MODEL_TILE`] pixels, row by row), `None` where a
/// tile has too little structure to measure one.
fn tile_shifts(lv: &Level, warp: &Warp) -> Vec<Option<WindowShift>> {
    let (lw, lh) = (lv.width(), lv.height());
    let tile = MODEL_TILE.min(lw / 4).min(lh / 4).max(8);
    let stride = stride_for(tile, tile, 512);
    (0..lh / tile)
        .flat_map(|ty| (0..lw / tile).map(move |tx| (tx, ty)))
        .map(|(tx, ty)| window_shift(lv, warp, (tx * tile, ty * tile, (tx + 1) * tile, (ty + 1) * tile), stride))
        .collect()
}

/// The translation model made robust to what moves differently from the image's majority: the tiles' residual
/// shifts ([`tile_shifts`]) combined by iteratively reweighted least squares with Tukey's biweight on their
/// Mahalanobis distances from the estimate (scale from their median), started at the component-wise median.
/// Roofs, crowns and walls stand metres above the ground, and between band cameras centimetres apart their
/// parallax differs from the ground's: the dense fit averages them in, the robust one follows the majority of the
/// image, as a single homography should.
fn robust_translation(lv: &Level, h: Homography) -> Homography {
    let mut h = h;
    for _pass in 0..2 {
        let tiles: Vec<WindowShift> = tile_shifts(lv, &Warp::from_homography(h)).into_iter().flatten().collect();
        if tiles.len() < 8 {
            return h;
        }
        let mut e = [0, 1].map(|c| {
            crate::util::stats::median(
                &tiles.iter().map(|t| if c == 0 { t.shift.0 } else { t.shift.1 }).collect::<Vec<_>>(),
            )
        });
        for _ in 0..20 {
            let q: Vec<f64> = tiles
                .iter()
                .map(|t| {
                    let (rx, ry) = (t.shift.0 - e[0], t.shift.1 - e[1]);
                    let [i0, i1, i2] = t.information;
                    (rx * rx * i0 + 2.0 * rx * ry * i1 + ry * ry * i2).max(0.0).sqrt()
                })
                .collect();
            let sigma = (crate::util::stats::median(&q) / (2.0 * std::f64::consts::LN_2).sqrt()).max(1e-12);
            let c = ROBUST_TUKEY * sigma;
            let (mut a, mut b) = ([0.0f64; 3], [0.0f64; 2]);
            for (t, &q) in tiles.iter().zip(&q) {
                let w = if q < c { (1.0 - (q / c).powi(2)).powi(2) } else { 0.0 };
                let [i0, i1, i2] = t.information;
                a[0] += w * i0;
                a[1] += w * i1;
                a[2] += w * i2;
                b[0] += w * (i0 * t.shift.0 + i1 * t.shift.1);
                b[1] += w * (i1 * t.shift.0 + i2 * t.shift.1);
            }
            let det = a[0] * a[2] - a[1] * a[1];
            if det.is_nan() || det <= 0.0 {
                return h;
            }
            let next = [(a[2] * b[0] - a[1] * b[1]) / det, (a[0] * b[1] - a[1] * b[0]) / det];
            let moved = (next[0] - e[0]).hypot(next[1] - e[1]);
            e = next;
            if moved < 1e-4 {
                break;
            }
        }
        if !(e[0].is_finite() && e[1].is_finite()) {
            return h;
        }
        h = h.mul(&Homography::translation(e[0], e[1]));
    }
    h
}

/// Side of the tiles [`choose_model`] measures on, in working-level pixels.
const MODEL_TILE: usize = 32;

/// The candidate (model, homography, correlation) the images support, by the Bayesian information criterion over
/// the translations left in tiles of the working level ([`tile_shifts`]): `chi^2 / kappa + p ln(2 n)` over the n
/// tiles every candidate measures, p the model's parameters, `chi^2` the tiles' residual shifts weighted by their
/// information and kappa the noise scale of the largest model's fit (its `chi^2` per degree of freedom). A model
/// with more parameters wins only where the images show what the smaller one cannot follow.
fn choose_model(lv: &Level, candidates: &[(AlignModel, Homography, f64)]) -> (AlignModel, Homography, f64) {
    let chi = |s: &WindowShift| {
        let ([i0, i1, i2], (x, y)) = (s.information, s.shift);
        x * x * i0 + 2.0 * x * y * i1 + y * y * i2
    };
    let tiles: Vec<Vec<Option<WindowShift>>> =
        candidates.iter().map(|c| tile_shifts(lv, &Warp::from_homography(c.1))).collect();
    let mut chi2 = vec![0.0f64; candidates.len()];
    let mut n = 0usize;
    for t in 0..tiles[0].len() {
        if tiles.iter().all(|c| c[t].is_some()) {
            for (k, c) in tiles.iter().enumerate() {
                chi2[k] += c[t].as_ref().map_or(0.0, chi);
            }
            n += 1;
        }
    }
    let params = |m: AlignModel| m.basis().len() as f64;
    let largest = (0..candidates.len()).max_by(|&a, &b| params(candidates[a].0).total_cmp(&params(candidates[b].0)));
    let Some(largest) = largest.filter(|_| n >= 8) else {
        return candidates.first().copied().unwrap_or((AlignModel::Homography, Homography::IDENTITY, 0.0));
    };
    let obs = 2.0 * n as f64;
    let kappa = (chi2[largest] / (obs - params(candidates[largest].0)).max(1.0)).max(1e-12);
    let bic = |k: usize| chi2[k] / kappa + params(candidates[k].0) * obs.ln();
    let best = (0..candidates.len()).min_by(|&a, &b| bic(a).total_cmp(&bic(b))).unwrap_or(largest);
    candidates[best]
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

/// A window's translation and how well the window constrains it.
#[derive(Debug, Clone, Copy)]
struct WindowShift {
    /// Shift in full-resolution pixels, applied to the template side of the warp: `warp(x + shift)`.
    shift: (f64, f64),
    /// `J^T J / sigma^2` (xx, xy, yy) per full-resolution pixel^2, sigma^2 from the window's residual, divided by
    /// the samples one blur footprint holds (neighbouring samples share their noise).
    information: [f64; 3],
}

/// Translation-only Lucas-Kanade with a gain on the orientation channels of level `lv` in the window
/// [x0, x1) x [y0, y1) (level pixels): the shift e with `I(warp(x + e)) ~ alpha T(x)`, the image sampled through
/// the full-resolution `warp` on the fly. `None` without enough valid samples or structure.
fn window_shift(
    lv: &Level,
    warp: &Warp,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    stride: usize,
) -> Option<WindowShift> {
    let w = lv.width();
    // Where every sample lands with no shift, and the local linear map of a template-side shift (level pixels
    // both): over a window the warp is affine to well below the shifts' precision.
    let map = |x: f64, y: f64| {
        let (u, v) = warp.apply(lv.up(x), lv.up(y));
        (lv.down(u), lv.down(v))
    };
    let (mx, my) = (0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64);
    let (c, ex, ey) = (map(mx, my), map(mx + 1.0, my), map(mx, my + 1.0));
    let jac = [ex.0 - c.0, ey.0 - c.0, ex.1 - c.1, ey.1 - c.1];
    let mut base: Vec<(f32, f32, f64, f64)> = Vec::new();
    for y in (y0..y1).step_by(stride) {
        for x in (x0..x1).step_by(stride) {
            let k = y * w + x;
            let (t0, t1) = (lv.t[0].data[k], lv.t[1].data[k]);
            if t0.is_finite() && t1.is_finite() {
                let (u, v) = map(x as f64, y as f64);
                base.push((t0, t1, u, v));
            }
        }
    }
    let mut d = (0.0f64, 0.0f64); // level pixels
    let mut pts: Vec<([f64; 4], [f64; 4])> = Vec::with_capacity(base.len());
    let mut info = [0.0; 3];
    for _ in 0..8 {
        pts.clear();
        let (du, dv) = (jac[0] * d.0 + jac[1] * d.1, jac[2] * d.0 + jac[3] * d.1);
        for &(t0, t1, u, v) in &base {
            if let Some(s) = lv.sample(u + du, v + dv) {
                // d/d(shift) = image gradient times the local map.
                let (g0x, g0y, g1x, g1y) = (s[2] as f64, s[3] as f64, s[4] as f64, s[5] as f64);
                let g = [
                    g0x * jac[0] + g0y * jac[2],
                    g0x * jac[1] + g0y * jac[3],
                    g1x * jac[0] + g1y * jac[2],
                    g1x * jac[1] + g1y * jac[3],
                ];
                pts.push(([t0 as f64, t1 as f64, s[0] as f64, s[1] as f64], g));
            }
        }
        if pts.len() < 50 {
            return None;
        }
        let (ii, ti) = pts
            .iter()
            .fold((0.0, 0.0), |(a, b), (v, _)| (a + v[2] * v[2] + v[3] * v[3], b + v[0] * v[2] + v[1] * v[3]));
        if !(ii > 0.0 && ti > 0.0) {
            return None;
        }
        let alpha = ti / ii;
        let (mut a11, mut a12, mut a22, mut b1, mut b2, mut ee) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (v, g) in &pts {
            for c in 0..2 {
                let e = alpha * v[2 + c] - v[c];
                let (jx, jy) = (alpha * g[2 * c], alpha * g[2 * c + 1]);
                a11 += jx * jx;
                a12 += jx * jy;
                a22 += jy * jy;
                b1 += jx * e;
                b2 += jy * e;
                ee += e * e;
            }
        }
        let det = a11 * a22 - a12 * a12;
        if det.is_nan() || det <= 1e-30 {
            return None;
        }
        let step = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det);
        d.0 -= step.0;
        d.1 -= step.1;
        let var = (ee / (2.0 * pts.len() as f64)).max(1e-12);
        // Samples per blur footprint: the blur's variance is STRUCTURE_BLUR / 2 pixels^2 per axis.
        let per_footprint =
            (4.0 * std::f64::consts::PI * 0.5 * STRUCTURE_BLUR as f64 / (stride * stride) as f64).max(1.0);
        let k = 1.0 / (var * per_footprint * lv.f * lv.f);
        info = [a11 * k, a12 * k, a22 * k];
        let moved = d.0.hypot(d.1);
        if moved.is_nan() || moved > 8.0 {
            return None;
        }
        if step.0.hypot(step.1) < 1e-3 {
            break;
        }
    }
    Some(WindowShift { shift: (d.0 * lv.f, d.1 * lv.f), information: info })
}

/// Largest translation left between the template and the image through `warp` on the four quadrants of
/// level `lv` (full-resolution pixels).
fn quadrant_residual(lv: &Level, warp: &Warp) -> f64 {
    let (w, h) = (lv.width(), lv.height());
    let stride = stride_for(w / 2, h / 2, GN_SAMPLES / 8);
    (0..4)
        .filter_map(|q| {
            let (x0, y0) = ((q % 2) * w / 2, (q / 2) * h / 2);
            window_shift(lv, warp, (x0 + 2, y0 + 2, x0 + w / 2 - 2, y0 + h / 2 - 2), stride)
        })
        .map(|s| s.shift.0.hypot(s.shift.1))
        .fold(0.0, f64::max)
}

/// Node spacing of the residual shift field, in target pixels.
pub const FIELD_STEP: f64 = 128.0;

/// Monomials x^a y^b with a + b <= degree, in a fixed order.
fn monomials(degree: usize) -> Vec<(i32, i32)> {
    (0..=degree as i32).flat_map(|d| (0..=d).map(move |b| (d - b, b))).collect()
}

/// The residual shift field on top of `h` (see [`super::warp`]), or `None` when the images do not call for one.
///
/// Every node of a [`FIELD_STEP`] grid measures the translation left in its window (one step wide, centred on the
/// node) with its information ([`window_shift`]). A lens model's error is smooth over the image, the
/// measurements' noise is not: the field is the polynomial in the image coordinates fitted to the nodes by
/// weighted least squares, of degree 2 (below, it is the homography's part) up to the largest with four nodes per
/// coefficient, the degree chosen by the Bayesian information criterion against no field at all, with the
/// measurements' noise scale taken from the fit of the largest degree. A field that does not explain the nodes
/// better than their noise is left out; so is any on images too small for a degree-2 fit.
fn fit_field(lv: &Level, h: &Homography, width: usize, height: usize) -> Option<ShiftField> {
    let mut field = ShiftField::zeros(width, height, FIELD_STEP);
    let (nx, ny) = (field.nx, field.ny);
    let half = 0.5 * FIELD_STEP / lv.f;
    let (lw, lh) = (lv.width(), lv.height());
    let stride = stride_for((2.0 * half) as usize, (2.0 * half) as usize, 4096);
    let s = 0.5 * width.max(height) as f64;
    let (cx, cy) = (0.5 * (width as f64 - 1.0), 0.5 * (height as f64 - 1.0));
    let mut chosen: Option<Vec<[f64; 2]>> = None;
    for _pass in 0..2 {
        let warp =
            Warp { homography: *h, field: chosen.as_ref().map(|d| ShiftField { d: d.clone(), ..field.clone() }) };
        // (normalised x, y; measured total shift; information)
        let mut meas: Vec<(f64, f64, [f64; 2], [f64; 3])> = Vec::new();
        for j in 0..ny {
            for k in 0..nx {
                let (fx, fy) = field.node(k, j);
                let (px, py) = (lv.down(fx), lv.down(fy));
                let win = (
                    (px - half).max(0.0) as usize,
                    (py - half).max(0.0) as usize,
                    ((px + half).ceil() as usize).min(lw),
                    ((py + half).ceil() as usize).min(lh),
                );
                if let Some(ws) = window_shift(lv, &warp, win, stride) {
                    let cur = chosen.as_ref().map_or([0.0; 2], |d| d[j * nx + k]);
                    meas.push((
                        (fx - cx) / s,
                        (fy - cy) / s,
                        [cur[0] + ws.shift.0, cur[1] + ws.shift.1],
                        ws.information,
                    ));
                }
            }
        }
        let n = meas.len();
        let mut dmax = 0usize;
        while monomials(dmax + 1).len() * 4 <= n {
            dmax += 1;
        }
        if monomials(0).len() * 4 > n {
            return None;
        }
        // Weighted fit of degree d: (coefficients, chi^2).
        let fit = |d: usize| -> Option<(Vec<f64>, f64)> {
            let mono = monomials(d);
            let p = mono.len();
            let m = 2 * p;
            let mut a = vec![0.0f64; m * m];
            let mut b = vec![0.0f64; m];
            for &(x, y, z, inf) in &meas {
                let phi: Vec<f64> = mono.iter().map(|&(ex, ey)| x.powi(ex) * y.powi(ey)).collect();
                let wm = [[inf[0], inf[1]], [inf[1], inf[2]]];
                for r in 0..m {
                    let (rc, rk) = (r / p, r % p);
                    for q in 0..m {
                        let (qc, qk) = (q / p, q % p);
                        a[r * m + q] += phi[rk] * wm[rc][qc] * phi[qk];
                    }
                    b[r] += phi[rk] * (wm[rc][0] * z[0] + wm[rc][1] * z[1]);
                }
            }
            for r in 0..m {
                a[r * m + r] *= 1.0 + 1e-9;
            }
            let c = solve(a, b)?;
            let chi2 = meas
                .iter()
                .map(|&(x, y, z, inf)| {
                    let phi: Vec<f64> = mono.iter().map(|&(ex, ey)| x.powi(ex) * y.powi(ey)).collect();
                    let fx: f64 = (0..p).map(|k| c[k] * phi[k]).sum();
                    let fy: f64 = (0..p).map(|k| c[p + k] * phi[k]).sum();
                    let (rx, ry) = (z[0] - fx, z[1] - fy);
                    rx * rx * inf[0] + 2.0 * rx * ry * inf[1] + ry * ry * inf[2]
                })
                .sum();
            Some((c, chi2))
        };
        let chi2_none: f64 = meas
            .iter()
            .map(|&(_, _, z, inf)| z[0] * z[0] * inf[0] + 2.0 * z[0] * z[1] * inf[1] + z[1] * z[1] * inf[2])
            .sum();
        let (_, chi2_max) = fit(dmax)?;
        let dof = (2 * n).saturating_sub(2 * monomials(dmax).len()).max(1);
        let kappa = (chi2_max / dof as f64).max(1.0);
        let ln_n = ((2 * n) as f64).ln();
        let mut best: (f64, Option<(usize, Vec<f64>)>) = (chi2_none / kappa, None);
        for d in 2..=dmax {
            if let Some((c, chi2)) = fit(d) {
                let bic = chi2 / kappa + (2 * monomials(d).len()) as f64 * ln_n;
                if bic < best.0 {
                    best = (bic, Some((d, c)));
                }
            }
        }
        let (d, c) = best.1?;
        let mono = monomials(d);
        let p = mono.len();
        let nodes: Vec<[f64; 2]> = (0..nx * ny)
            .map(|idx| {
                let (fx, fy) = field.node(idx % nx, idx / nx);
                let (x, y) = ((fx - cx) / s, (fy - cy) / s);
                let phi: Vec<f64> = mono.iter().map(|&(ex, ey)| x.powi(ex) * y.powi(ey)).collect();
                [(0..p).map(|k| c[k] * phi[k]).sum(), (0..p).map(|k| c[p + k] * phi[k]).sum()]
            })
            .collect();
        chosen = Some(nodes);
    }
    let d = chosen?;
    field.d = d;
    Some(field)
}

/// Largest translation left between `t` and `i` warped by `warp` (any two planes of one size, e.g.
/// [`gradient_image`]s): translation-only Lucas-Kanade on the four quadrants of their orientation fields.
pub fn residual_shift(t: &Plane, i: &Plane, warp: &Warp) -> f64 {
    quadrant_residual(&Level::new(t, i, 0), warp)
}
