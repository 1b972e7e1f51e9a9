//! Photometric refinement of a surface point against the training images: a plane sweep along one line, scored by
//! normalised cross-correlation (NCC), as multi-view stereo refines a depth-map pixel (COLMAP's PatchMatch stereo,
//! Schönberger et al. 2016, scores a patch on a plane by the NCC between views in the same way).
//!
//! For a point P0, a unit search direction u (the export's ray, or world down for a DSM cell) and a plane normal n:
//! - candidate points P(s) = P0 + s u for s = k h, k = -K..K, with h one pixel footprint of the reference view at P0
//!   (distance / focal length) and K = `range`;
//! - at each candidate, a (2 `half` + 1)^2 grid of points on the plane through P(s) with normal n, spaced one
//!   footprint apart, is projected into every view and sampled bilinearly (pixel centres at +0.5, as the ray
//!   generator's);
//! - each view's patch may lose its least-squares polynomial trend (`trend_degree`: quadratic for the DSM, none for
//!   the cloud): smooth shading (a sunlit slope, the vegetation's hotspot, an albedo ramp) correlates between views
//!   at any height, so on a uniform surface plain NCC finds a high score at a height it made up; what is left is
//!   texture (and, on coarse noisy images, little else: the cloud keeps plain NCC);
//! - the score is the mean over the partner views (all but the reference, `views[0]`) of the NCC between the
//!   reference's samples and the partner's, averaged over the bands where both patches vary (an NCC is blind to a
//!   band's gain and offset, so a dark, weakly textured material counts as much as a bright one: a plain squared
//!   error weighs texture by its absolute contrast squared);
//! - the best k, then a parabola through it and its neighbours, then the same on a grid four times finer around it.
//!
//! The images support the point when the best score reaches `min_ncc`, at least `min_views` partners scored it, and
//! the best coarse k is not at the end of the range (a peak there may lie beyond it). Otherwise it stays where the
//! field put it, unsupported: a uniform surface (water, a fresh sports field) has no texture to correlate, and the
//! refinement leaves it to the field and the export's filters.
//!
//! A supported point moves only when the best score also reaches `move_ncc`: a plane patch fits a flat surface (a
//! road, a roof, a lawn) to an NCC near 1, but not a tree crown's dome a few patches wide, where the best of a weak
//! correlation lines up silhouettes below the crown's surface. Between the two thresholds the images confirm that a
//! surface is there but do not place it better than the field does; on the campus run the broadleaf crowns' median
//! distance to the truth was 0.16 m where the field put them and 0.46 m where every supported point moved
//! (docs/geometry.md).
//!
//! The DSM checks each supported cell with a second sweep from another reference ([`super::cross_check`]).
//!
//! Everything is f64 on the CPU; no kernel. The test (`tests/outputs/photometric_refine.rs`) checks it against an
//! independent NCC written from the formula and on rendered planes of known height.

use crate::data::camera::project_point_subpixel;
use crate::data::Camera;

/// Settings of the plane sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineOptions {
    /// Patch half-size in footprints: (2 half + 1)^2 samples per view.
    pub half: usize,
    /// Search range in reference footprints each side of the point.
    pub range: usize,
    /// Smallest best mean NCC that supports a point (below it the point is unsupported).
    pub min_ncc: f64,
    /// Smallest best mean NCC that moves a supported point (below it the point keeps the field's position).
    pub move_ncc: f64,
    /// Partner views (besides the reference) a score needs.
    pub min_views: usize,
    /// Degree of the polynomial trend removed from every patch before it is correlated (0: the mean only, which the
    /// NCC removes anyway; the DSM's default is 2, [`RefineOptions::dsm`]). Shading that varies smoothly across an image (a sunlit slope, the vegetation's hotspot,
    /// vignetting left in the images) correlates between views at any height, and on uniform surfaces a sweep's best
    /// score then lies at a wrong height with a high NCC; without its quadratic trend a patch keeps only texture.
    pub trend_degree: usize,
    /// Drop the points the images do not support (no score, a best NCC below `min_ncc`, or a peak at the end of the
    /// range), as MVS fusion drops pixels without photometric support; false keeps them where the field put them.
    pub drop_unsupported: bool,
    /// Cross-check of the DSM's cells: a second sweep with another reference view must find its peak within this
    /// many reference footprints of the first, or the cell is not supported (stereo's left-right check). None: off.
    pub cross_check: Option<f64>,
}

impl RefineOptions {
    /// The DSM's refinement: each patch's quadratic trend removed, the cross-check on, and a cell without support
    /// kept (the fill decides what becomes of it). The cloud keeps plain NCC (the [`Default`]): on a noisy flight at
    /// 0.11 m ground sampling, trend removal left a sixth of its points (docs/results/terrain.md), where the DSM's
    /// cross-check and fill make up for the cells it sets apart.
    pub fn dsm() -> Self {
        Self { trend_degree: 2, cross_check: Some(1.0), drop_unsupported: false, ..Self::default() }
    }
}

impl Default for RefineOptions {
    fn default() -> Self {
        Self {
            half: 3,
            range: 8,
            min_ncc: 0.5,
            move_ncc: 0.85,
            min_views: 2,
            trend_degree: 0,
            drop_unsupported: true,
            cross_check: None,
        }
    }
}

/// One view's image for patch sampling: its pose in the frame the points are in, and per band a row-major plane.
pub struct PatchView<'a> {
    pub origin: [f64; 3],
    /// Rows of the camera-to-world rotation (as [`project_point_subpixel`] takes it).
    pub rot: [[f64; 3]; 3],
    pub cam: &'a Camera,
    /// One plane per band, `cam.width * cam.height` values each.
    pub planes: Vec<&'a [f32]>,
}

/// Where a point went.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refined {
    /// Offset along the search direction (0 when the point did not move).
    pub s: f64,
    /// Best mean NCC found (NaN when no candidate could be scored).
    pub ncc: f64,
    /// Whether the point moved (see the module's conditions).
    pub moved: bool,
    /// Whether the images support a surface at or near the point (`moved` implies it).
    pub supported: bool,
    /// Offset of the best score along the search direction whether or not the point moved (NaN when unsupported).
    pub peak: f64,
}

/// Bilinear sample of `plane` (width w, height h) at image position (u, v), pixel centres at +0.5; None outside the
/// pixel centres' hull or on a non-finite value.
pub fn bilinear(plane: &[f32], w: u32, h: u32, u: f64, v: f64) -> Option<f64> {
    let (x, y) = (u - 0.5, v - 0.5);
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = ((x.floor() as u32).min(w.saturating_sub(2)), (y.floor() as u32).min(h.saturating_sub(2)));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |c: u32, r: u32| plane[(r * w + c) as usize] as f64;
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let v = (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy) + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy;
    v.is_finite().then_some(v)
}

/// Normalised cross-correlation of two equally long sample vectors; None when either hardly varies (relative
/// variance below 1e-10 of the mean square, or an absolute one below 1e-14).
pub fn ncc(a: &[f64], b: &[f64]) -> Option<f64> {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb, mut qa, mut qb) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
        qa += x * x;
        qb += y * y;
    }
    let flat = |s: f64, q: f64| s <= 1e-14 * n || s <= 1e-10 * q;
    if flat(saa, qa) || flat(sbb, qb) {
        return None;
    }
    Some((sab / (saa * sbb).sqrt()).clamp(-1.0, 1.0))
}

/// Orthonormal basis (Gram-Schmidt, in f64) of the polynomials in the patch's two axes of total degree <= `degree`,
/// sampled on its `side` x `side` grid (row-major, centred): 1, x, y, x^2, xy, y^2, ...
pub fn trend_basis(side: usize, degree: usize) -> Vec<Vec<f64>> {
    let h = (side as f64 - 1.0) / 2.0;
    let mut out: Vec<Vec<f64>> = Vec::new();
    for d in 0..=degree {
        for px in 0..=d {
            let py = d - px;
            let mut v: Vec<f64> = (0..side * side)
                .map(|k| ((k / side) as f64 - h).powi(px as i32) * ((k % side) as f64 - h).powi(py as i32))
                .collect();
            for q in &out {
                let dot: f64 = q.iter().zip(&v).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(q).for_each(|(x, qq)| *x -= dot * qq);
            }
            // A term the grid cannot tell from the earlier ones (a patch too small for the degree) is left out.
            let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if n > 1e-9 {
                v.iter_mut().for_each(|x| *x /= n);
                out.push(v);
            }
        }
    }
    out
}

/// Removes from `patch` its projection on the orthonormal `basis` ([`trend_basis`]): its least-squares polynomial.
pub fn remove_trend(patch: &mut [f64], basis: &[Vec<f64>]) {
    for q in basis {
        let d: f64 = q.iter().zip(patch.iter()).map(|(a, b)| a * b).sum();
        patch.iter_mut().zip(q).for_each(|(x, qq)| *x -= d * qq);
    }
}

/// Two unit vectors spanning the plane with normal `n` (the first horizontal when n is not vertical).
pub fn plane_axes(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let n = glam::DVec3::from(n).normalize();
    let helper = if n.z.abs() < 0.9 { glam::DVec3::Z } else { glam::DVec3::X };
    let e1 = helper.cross(n).normalize();
    let e2 = n.cross(e1);
    (e1.to_array(), e2.to_array())
}

/// Mean NCC of the patch on the plane through `p` (spanned by `axes`, samples `spacing` apart) between `views[0]`
/// and each other view, over every band, with the number of partners that scored. Each patch's polynomial `trend`
/// ([`trend_basis`] of its side; empty: none) is removed first. `scratch` is reused.
pub fn score(
    p: [f64; 3],
    axes: ([f64; 3], [f64; 3]),
    spacing: f64,
    half: usize,
    trend: &[Vec<f64>],
    views: &[PatchView],
    scratch: &mut Vec<f64>,
) -> (Option<f64>, usize) {
    let side = 2 * half + 1;
    let m = side * side;
    let nb = views[0].planes.len();
    // Samples per view: band-major, m per band; None for a view whose patch leaves the image.
    scratch.clear();
    scratch.resize(views.len() * nb * m, f64::NAN);
    let mut ok = vec![true; views.len()];
    for (vi, v) in views.iter().enumerate() {
        'pts: for i in 0..side {
            for j in 0..side {
                let (a, b) = ((i as f64 - half as f64) * spacing, (j as f64 - half as f64) * spacing);
                let q = [0, 1, 2].map(|k| p[k] + a * axes.0[k] + b * axes.1[k]);
                let Some((u, vv, _)) = project_point_subpixel(v.cam, v.origin, &v.rot, q) else {
                    ok[vi] = false;
                    break 'pts;
                };
                for (bi, plane) in v.planes.iter().enumerate() {
                    match bilinear(plane, v.cam.width, v.cam.height, u, vv) {
                        Some(x) => scratch[(vi * nb + bi) * m + i * side + j] = x,
                        None => {
                            ok[vi] = false;
                            break 'pts;
                        }
                    }
                }
            }
        }
    }
    if !ok[0] {
        return (None, 0);
    }
    // Each patch's trend (a smooth shading ramp or a hotspot that moves with the camera) is removed, so that only
    // its texture correlates. A patch whose texture is below 1e-10 of its mean square counts as flat (as `ncc`
    // judges a patch before the trend is removed).
    let mut flat = vec![false; views.len() * nb];
    if !trend.is_empty() {
        for vi in (0..views.len()).filter(|&vi| ok[vi]) {
            for bi in 0..nb {
                let patch = &mut scratch[(vi * nb + bi) * m..(vi * nb + bi + 1) * m];
                let before: f64 = patch.iter().map(|x| x * x).sum();
                remove_trend(patch, trend);
                flat[vi * nb + bi] = patch.iter().map(|x| x * x).sum::<f64>() <= 1e-10 * before;
            }
        }
    }
    let (mut sum, mut partners) = (0.0, 0usize);
    for vi in 1..views.len() {
        if !ok[vi] {
            continue;
        }
        let (mut s, mut k) = (0.0, 0usize);
        for bi in 0..nb {
            let a = &scratch[bi * m..(bi + 1) * m];
            let b = &scratch[(vi * nb + bi) * m..(vi * nb + bi + 1) * m];
            if flat[bi] || flat[vi * nb + bi] {
                continue;
            }
            if let Some(c) = ncc(a, b) {
                s += c;
                k += 1;
            }
        }
        if k > 0 {
            sum += s / k as f64;
            partners += 1;
        }
    }
    if partners == 0 {
        return (None, 0);
    }
    (Some(sum / partners as f64), partners)
}

/// Whether a view (`cam` at `origin`, rotation rows `rot`) holds the whole sweep of `p0` along the unit direction `u`
/// as the reference: the corners of the patch (normal `n`, samples one footprint of this view apart) at both ends of
/// the search range project inside its pixel centres' hull. A reference whose patch leaves its image scores
/// nothing there, and the point is left unsupported for the view's sake, not the surface's.
#[allow(clippy::too_many_arguments)]
pub fn holds_sweep(
    cam: &Camera,
    origin: [f64; 3],
    rot: &[[f64; 3]; 3],
    p0: [f64; 3],
    u: [f64; 3],
    n: [f64; 3],
    o: &RefineOptions,
) -> bool {
    let h = (glam::DVec3::from(p0) - glam::DVec3::from(origin)).length() / (0.5 * (cam.fx + cam.fy));
    let axes = plane_axes(n);
    let (k, r) = (o.range as f64 * h, o.half as f64 * h);
    let inside = |q: [f64; 3]| {
        project_point_subpixel(cam, origin, rot, q).is_some_and(|(x, y, _)| {
            x >= 0.5 && y >= 0.5 && x <= cam.width as f64 - 0.5 && y <= cam.height as f64 - 0.5
        })
    };
    [-k, k].iter().all(|&s| {
        [(-r, -r), (-r, r), (r, -r), (r, r)]
            .iter()
            .all(|&(a, b)| inside([0, 1, 2].map(|i| p0[i] + s * u[i] + a * axes.0[i] + b * axes.1[i])))
    })
}

/// Vertex of the parabola through (-1, a), (0, b), (1, c), clamped to [-1, 1] (0 when the three are not a peak).
fn parabola_peak(a: f64, b: f64, c: f64) -> f64 {
    let den = a - 2.0 * b + c;
    if !(den < 0.0 && den.is_finite()) {
        return 0.0;
    }
    (0.5 * (a - c) / den).clamp(-1.0, 1.0)
}

/// Refines `p0` along the unit direction `u` with the patch plane's normal `n`; `footprint` is one pixel footprint
/// of the reference view at `p0` (in the points' units). `views[0]` is the reference view. See the module.
pub fn refine(
    p0: [f64; 3],
    u: [f64; 3],
    n: [f64; 3],
    footprint: f64,
    views: &[PatchView],
    o: &RefineOptions,
) -> Refined {
    let keep = |ncc: f64| Refined { s: 0.0, ncc, moved: false, supported: false, peak: f64::NAN };
    if views.len() < 1 + o.min_views.max(1) || footprint.is_nan() || footprint <= 0.0 {
        return keep(f64::NAN);
    }
    let axes = plane_axes(n);
    let trend = if o.trend_degree == 0 { Vec::new() } else { trend_basis(2 * o.half + 1, o.trend_degree) };
    let mut scratch = Vec::new();
    let mut eval = |s: f64| {
        let p = [0, 1, 2].map(|k| p0[k] + s * u[k]);
        match score(p, axes, footprint, o.half, &trend, views, &mut scratch) {
            (Some(c), partners) if partners >= o.min_views => Some(c),
            _ => None,
        }
    };
    let k_max = o.range as i64;
    let coarse: Vec<Option<f64>> = (-k_max..=k_max).map(|k| eval(k as f64 * footprint)).collect();
    let Some((best, best_c)) =
        coarse.iter().enumerate().filter_map(|(i, c)| c.map(|c| (i, c))).max_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return keep(f64::NAN);
    };
    if best_c < o.min_ncc || best == 0 || best == coarse.len() - 1 {
        return keep(best_c);
    }
    let at = |i: usize| coarse[i].unwrap_or(f64::NEG_INFINITY);
    let s1 = (best as i64 - k_max) as f64 * footprint + parabola_peak(at(best - 1), best_c, at(best + 1)) * footprint;
    // Fine pass: a quarter footprint each side of the coarse vertex.
    let h = 0.25 * footprint;
    let (a, b, c) = (eval(s1 - h), eval(s1), eval(s1 + h));
    let (s, ncc) = match (a, b, c) {
        (Some(a), Some(b), Some(c)) if b >= a && b >= c => (s1 + parabola_peak(a, b, c) * h, b),
        // The vertex was off: the best of the three scored points.
        _ => [(s1 - h, a), (s1, b), (s1 + h, c)]
            .into_iter()
            .filter_map(|(s, v)| v.map(|v| (s, v)))
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .unwrap_or((s1, best_c)),
    };
    if !s.is_finite() {
        return keep(best_c);
    }
    let ncc = ncc.max(best_c);
    if ncc < o.move_ncc {
        return Refined { s: 0.0, ncc, moved: false, supported: true, peak: s };
    }
    Refined { s, ncc, moved: true, supported: true, peak: s }
}
