//! Calibration panels: the panel region (found in the image, or given as four corners), its statistics, and the
//! irradiance it implies, `E = pi * mean(L_panel) / rho_panel` (MicaSense `Panel.irradiance_mean`, ODM).
//!
//! Detection: a panel is the largest bright, uniform, square-ish patch. At half resolution, pixels whose 9x9
//! neighbourhood has a coefficient of variation below 4 % and a mean above the image's 75th percentile form
//! connected components; the largest one whose four extreme points make a square (sides within a factor 1.33 of
//! each other, at least 20 px plus the window) that it fills to at least 80 % is the panel. Its corners are those extreme points, pushed
//! out by the window's half width (the uniformity test erodes the patch by that much). Statistics are taken on
//! the central part, the quadrilateral scaled by [`PANEL_INNER`] about its centre: on the RedEdge panel capture
//! of tests/fixtures/real the bright square is 220 px wide and MicaSense's own panel region (from the QR code and
//! the panel's layout) the central 161 px, so edge blur and the border of the reflective area stay out.

use super::error::RigError;
use super::plane::Plane;
use std::path::Path;

/// Four corners (x, y) in pixel-centre coordinates, ordered counter-clockwise in the image as drawn.
pub type Quad = [[f64; 2]; 4];

/// The part of the detected panel (linear scale about its centre) whose pixels are averaged.
pub const PANEL_INNER: f64 = 0.74;

/// Orders four points by angle around their centroid.
pub fn order_corners(mut q: Quad) -> Quad {
    let cx = q.iter().map(|p| p[0]).sum::<f64>() / 4.0;
    let cy = q.iter().map(|p| p[1]).sum::<f64>() / 4.0;
    q.sort_by(|a, b| {
        let ta = (a[1] - cy).atan2(a[0] - cx);
        let tb = (b[1] - cy).atan2(b[0] - cx);
        ta.total_cmp(&tb)
    });
    q
}

/// `q` scaled about its centroid by `f` (0.9 = shrunk by 10 %).
pub fn scale_quad(q: &Quad, f: f64) -> Quad {
    let cx = q.iter().map(|p| p[0]).sum::<f64>() / 4.0;
    let cy = q.iter().map(|p| p[1]).sum::<f64>() / 4.0;
    q.map(|p| [cx + f * (p[0] - cx), cy + f * (p[1] - cy)])
}

/// Whether pixel centre (x, y) lies in the convex quad `q` (corners in order, as [`order_corners`] gives them;
/// points on an edge count as inside).
pub fn in_quad(q: &Quad, x: f64, y: f64) -> bool {
    let mut twice_area = 0.0;
    for i in 0..4 {
        let (p, r) = (q[i], q[(i + 1) % 4]);
        twice_area += p[0] * r[1] - r[0] * p[1];
    }
    let sign = if twice_area >= 0.0 { 1.0 } else { -1.0 };
    (0..4).all(|i| {
        let (a, b) = (q[i], q[(i + 1) % 4]);
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let d = (ex * (y - a[1]) - ey * (x - a[0])) / ex.hypot(ey).max(1e-12);
        d * sign >= -1e-9
    })
}

/// Statistics of a region.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RegionStats {
    pub mean: f64,
    pub std: f64,
    pub count: usize,
    /// Pixels excluded because the raw value was saturated.
    pub saturated: usize,
}

/// Mean and standard deviation of `img` inside `q`, skipping pixels where `exclude` is true.
pub fn region_stats(img: &Plane, q: &Quad, exclude: impl Fn(usize, usize) -> bool) -> RegionStats {
    let xs = q.iter().map(|p| p[0]);
    let ys = q.iter().map(|p| p[1]);
    let x0 = xs.clone().fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
    let x1 = (xs.fold(f64::NEG_INFINITY, f64::max).ceil() as usize).min(img.width.saturating_sub(1));
    let y0 = ys.clone().fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
    let y1 = (ys.fold(f64::NEG_INFINITY, f64::max).ceil() as usize).min(img.height.saturating_sub(1));
    let (mut n, mut s, mut s2, mut sat) = (0usize, 0.0f64, 0.0f64, 0usize);
    let ordered = order_corners(*q);
    for y in y0..=y1 {
        for x in x0..=x1 {
            if !in_quad(&ordered, x as f64, y as f64) {
                continue;
            }
            if exclude(x, y) {
                sat += 1;
                continue;
            }
            let v = img.at(x, y) as f64;
            n += 1;
            s += v;
            s2 += v * v;
        }
    }
    let mean = if n > 0 { s / n as f64 } else { f64::NAN };
    let var = if n > 1 { ((s2 - s * s / n as f64) / (n - 1) as f64).max(0.0) } else { 0.0 };
    RegionStats { mean, std: var.sqrt(), count: n, saturated: sat }
}

/// Irradiance from the panel's mean radiance and its reflectance.
pub fn irradiance_from_panel(mean_radiance: f64, reflectance: f64) -> f64 {
    std::f64::consts::PI * mean_radiance / reflectance
}

/// Finds the panel in a panel capture's band image (any linear units). `saturated` marks pixels to leave out
/// of the uniformity test (saturated raw values): they neither break a panel apart nor make one.
pub fn detect_panel(img: &Plane, saturated: &[bool], path: &Path) -> Result<Quad, RigError> {
    const R: usize = 4;
    let small = img.downsample();
    let (w, h) = (small.width, small.height);
    if w < 4 * R || h < 4 * R {
        return Err(RigError::PanelNotFound { path: path.into(), reason: "image too small".into() });
    }
    let bad = |x: usize, y: usize| {
        let i = 2 * y * img.width + 2 * x;
        saturated.get(i).copied().unwrap_or(false)
            || saturated.get(i + 1).copied().unwrap_or(false)
            || saturated.get(i + img.width).copied().unwrap_or(false)
            || saturated.get(i + img.width + 1).copied().unwrap_or(false)
    };
    // Integral images of v, v^2 and the count of usable pixels.
    let mut ii = vec![0.0f64; (w + 1) * (h + 1)];
    let mut ii2 = vec![0.0f64; (w + 1) * (h + 1)];
    let mut iin = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let (mut rs, mut rs2, mut rn) = (0.0, 0.0, 0.0);
        for x in 0..w {
            let v = small.at(x, y) as f64;
            if v.is_finite() && !bad(x, y) {
                rs += v;
                rs2 += v * v;
                rn += 1.0;
            }
            let (i, above) = ((y + 1) * (w + 1) + x + 1, y * (w + 1) + x + 1);
            ii[i] = ii[above] + rs;
            ii2[i] = ii2[above] + rs2;
            iin[i] = iin[above] + rn;
        }
    }
    let mut sorted: Vec<f32> = small.data.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f32::total_cmp);
    let p75 = sorted[sorted.len() * 3 / 4] as f64;
    let full = ((2 * R + 1) * (2 * R + 1)) as f64;
    let mut mask = vec![false; w * h];
    for y in R..h - R {
        for x in R..w - R {
            let (xa, xb, ya, yb) = (x - R, x + R + 1, y - R, y + R + 1);
            let box_sum =
                |t: &[f64]| t[yb * (w + 1) + xb] - t[ya * (w + 1) + xb] - t[yb * (w + 1) + xa] + t[ya * (w + 1) + xa];
            let n = box_sum(&iin);
            if n < 0.5 * full {
                continue;
            }
            let m = box_sum(&ii) / n;
            let var = (box_sum(&ii2) / n - m * m).max(0.0);
            mask[y * w + x] = m > p75 && m > 0.0 && var.sqrt() < 0.04 * m;
        }
    }
    // Connected components (4-neighbour), iterative flood fill.
    let mut label = vec![0u32; w * h];
    let mut best: Option<(usize, Quad)> = None;
    let mut next = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !mask[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        label[start] = next;
        stack.push(start);
        let mut pts: Vec<(usize, usize)> = Vec::new();
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            pts.push((x, y));
            let mut push = |j: usize| {
                if mask[j] && label[j] == 0 {
                    label[j] = next;
                    stack.push(j);
                }
            };
            if x > 0 {
                push(i - 1);
            }
            if x + 1 < w {
                push(i + 1);
            }
            if y > 0 {
                push(i - w);
            }
            if y + 1 < h {
                push(i + w);
            }
        }
        if pts.len() < 100 || best.as_ref().is_some_and(|(a, _)| *a >= pts.len()) {
            continue;
        }
        let ext = |f: &dyn Fn(&(usize, usize)) -> f64| {
            let p = pts.iter().max_by(|a, b| f(a).total_cmp(&f(b))).unwrap();
            [p.0 as f64, p.1 as f64]
        };
        let quad = order_corners([
            ext(&|p| (p.0 + p.1) as f64),
            ext(&|p| -((p.0 + p.1) as f64)),
            ext(&|p| p.0 as f64 - p.1 as f64),
            ext(&|p| p.1 as f64 - p.0 as f64),
        ]);
        let (bx0, bx1) = (pts.iter().map(|p| p.0).min().unwrap(), pts.iter().map(|p| p.0).max().unwrap());
        let (by0, by1) = (pts.iter().map(|p| p.1).min().unwrap(), pts.iter().map(|p| p.1).max().unwrap());
        let aspect = (bx1 - bx0 + 1) as f64 / (by1 - by0 + 1) as f64;
        let area = quad_area(&quad).max(1.0);
        let fill = pts.len() as f64 / area;
        let sides: Vec<f64> =
            (0..4).map(|i| (quad[i][0] - quad[(i + 1) % 4][0]).hypot(quad[i][1] - quad[(i + 1) % 4][1])).collect();
        let (smin, smax) =
            (sides.iter().cloned().fold(f64::INFINITY, f64::min), sides.iter().cloned().fold(0.0, f64::max));
        let square = smax <= 1.33 * smin && smin >= 10.0;
        if square && (0.5..=2.0).contains(&aspect) && fill > 0.8 && fill < 1.3 {
            best = Some((pts.len(), quad));
        }
    }
    let Some((_, quad)) = best else {
        return Err(RigError::PanelNotFound {
            path: path.into(),
            reason: "no bright, uniform, square patch of at least 20x20 pixels".into(),
        });
    };
    // Back to full resolution (a half-resolution pixel centre x maps to 2x + 0.5), pushed out by the window.
    let cx = quad.iter().map(|p| p[0]).sum::<f64>() / 4.0;
    let cy = quad.iter().map(|p| p[1]).sum::<f64>() / 4.0;
    Ok(quad.map(|p| {
        let (dx, dy) = (p[0] - cx, p[1] - cy);
        let len = dx.hypot(dy).max(1e-9);
        let grow = R as f64 * std::f64::consts::SQRT_2;
        [2.0 * (p[0] + dx / len * grow) + 0.5, 2.0 * (p[1] + dy / len * grow) + 0.5]
    }))
}

/// Area of a quad (shoelace, corners in order).
pub fn quad_area(q: &Quad) -> f64 {
    let q = order_corners(*q);
    let mut a = 0.0;
    for i in 0..4 {
        let (p, r) = (q[i], q[(i + 1) % 4]);
        a += p[0] * r[1] - r[0] * p[1];
    }
    0.5 * a.abs()
}
