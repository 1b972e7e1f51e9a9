//! One capture through the chain: raw -> radiance (-> reflectance) per band, the band warps (estimated here,
//! or shared across the flight), one resampling per band into the target camera, the crop to the area every
//! band of every capture covers (one image size for the whole dataset), the float32 multi-band TIFF, and an
//! 8-bit PNG of the reference band for SfM tools (`sfm_images/`).

use std::path::Path;

use super::calib::BandFile;
use super::capture::Capture;
use super::error::RigError;
use super::lens::{resample, Target};
use super::meta::read_pixels;
use super::plane::Plane;
use super::radiometry::to_radiance;
use super::register::{align, fit_homography, rig_homography, AlignStats, Homography};
use super::warp::{ShiftField, Warp};
use crate::util::tiff::{write_tiff, TiffData};

/// Registration of one band of one capture.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BandRegistration {
    pub band: String,
    pub warp: Warp,
    pub stats: Option<AlignStats>,
}

/// One written frame.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameOut {
    pub capture: String,
    pub file: String,
    pub width: usize,
    pub height: usize,
    pub fx: f64,
    pub cx: f64,
    pub cy: f64,
    pub saturated: Vec<usize>,
    pub registration: Vec<BandRegistration>,
    /// Per band, the median and 99th percentile of the written values (a strided sample).
    pub value_quantiles: Vec<[f32; 2]>,
}

/// A capture's bands in output units, with each band's count of saturated pixels.
pub struct Loaded {
    pub values: Vec<Plane>,
    pub saturated: Vec<usize>,
}

/// Reads and converts every band; `irradiance` (per band) turns radiance into reflectance `pi L / E`.
pub fn load(cap: &Capture, irradiance: Option<&[f64]>) -> Result<Loaded, RigError> {
    let mut values = Vec::with_capacity(cap.bands.len());
    let mut saturated = Vec::with_capacity(cap.bands.len());
    for (bi, b) in cap.bands.iter().enumerate() {
        let raw = read_pixels(&b.meta)?;
        let (mut plane, stats) = to_radiance(b, &raw);
        saturated.push(stats.saturated);
        if let Some(e) = irradiance {
            let k = (std::f64::consts::PI / e[bi]) as f32;
            plane.data.iter_mut().for_each(|v| *v *= k);
        }
        values.push(plane);
    }
    Ok(Loaded { values, saturated })
}

/// The undistorted camera of the reference band (its raw geometry when `undistort` is off or it has no lens
/// model).
pub fn target_for(cap: &Capture, ref_idx: usize, undistort: bool) -> Target {
    let r = &cap.bands[ref_idx];
    let (w, h) = (r.meta.width as usize, r.meta.height as usize);
    match r.lens.filter(|_| undistort) {
        Some(l) => Target { width: w, height: h, f: 0.5 * (l.fx + l.fy), cx: l.cx, cy: l.cy },
        None => Target { width: w, height: h, f: 1.0, cx: 0.0, cy: 0.0 },
    }
}

fn lens_of(b: &BandFile, undistort: bool) -> Option<super::calib::Lens> {
    b.lens.filter(|_| undistort)
}

/// Initial band homography from the rig data (target pixels of the reference -> target pixels of the band).
pub fn rig_guess(r: &BandFile, b: &BandFile, t: &Target) -> Homography {
    let mut h = Homography::IDENTITY;
    if let (Some(rr), Some(rb)) = (r.rig_relatives, b.rig_relatives) {
        let to_band = rig_homography(rb, t.f, t.cx, t.cy);
        let to_ref = rig_homography(rr, t.f, t.cx, t.cy);
        if let Some(inv) = to_ref.inverse() {
            h = to_band.mul(&inv);
        }
    }
    if let (Some(cr), Some(cb)) = (r.relative_center, b.relative_center) {
        h = Homography::translation(cb[0] - cr[0], cb[1] - cr[1]).mul(&h);
    }
    h
}

/// Estimates every band's warp on this capture (`register` off: the rig's guess alone).
pub fn estimate_warps(
    cap: &Capture,
    l: &Loaded,
    ref_idx: usize,
    undistort: bool,
    register: bool,
) -> Vec<BandRegistration> {
    let target = target_for(cap, ref_idx, undistort);
    let r = &cap.bands[ref_idx];
    let ref_plane =
        register.then(|| resample(&l.values[ref_idx], &target, lens_of(r, undistort).as_ref(), &Warp::identity()));
    cap.bands
        .iter()
        .enumerate()
        .map(|(bi, b)| {
            if bi == ref_idx {
                return BandRegistration { band: b.band_name.clone(), warp: Warp::identity(), stats: None };
            }
            let guess = rig_guess(r, b, &target);
            match &ref_plane {
                Some(rp) => {
                    let img = resample(&l.values[bi], &target, lens_of(b, undistort).as_ref(), &Warp::identity());
                    let (warp, st) = align(rp, &img, guess);
                    BandRegistration { band: b.band_name.clone(), warp, stats: Some(st) }
                }
                None => BandRegistration { band: b.band_name.clone(), warp: Warp::from_homography(guess), stats: None },
            }
        })
        .collect()
}

/// The rig data's warps alone (no image alignment), without reading pixels.
pub fn rig_only_warps(cap: &Capture, ref_idx: usize, undistort: bool) -> Vec<BandRegistration> {
    let target = target_for(cap, ref_idx, undistort);
    let r = &cap.bands[ref_idx];
    cap.bands
        .iter()
        .map(|b| BandRegistration {
            band: b.band_name.clone(),
            warp: Warp::from_homography(rig_guess(r, b, &target)),
            stats: None,
        })
        .collect()
}

fn median(v: Vec<f64>) -> f64 {
    crate::util::stats::median(&v)
}

/// Sampled captures whose alignment correlates less than this share of the band's median correlation are left
/// out of the shared warp (a capture over water, a blurred one).
pub const RIG_MIN_CORRELATION_SHARE: f64 = 0.5;

/// A sampled capture whose warp lies farther from the median than this many times the sample's median distance
/// (and at least [`RIG_OUTLIER_MIN_PX`]) is left out of the shared warp.
pub const RIG_OUTLIER_FACTOR: f64 = 3.0;

/// The smallest distance (pixels) from the median that makes a sampled capture an outlier.
pub const RIG_OUTLIER_MIN_PX: f64 = 0.25;

/// The captures of a band's sample that [`median_warps`] keeps: finite warps, a correlation (when the alignment
/// reported one) at least [`RIG_MIN_CORRELATION_SHARE`] of the median, a quadrant residual at most three times
/// the median (and at least half a pixel), and a warp within [`RIG_OUTLIER_FACTOR`] times the median distance of
/// the median warp at a 3x3 grid of probe points. Returns the kept indices (all of them if the tests would leave
/// none).
pub fn rig_inliers(regs: &[&BandRegistration], width: usize, height: usize) -> Vec<usize> {
    let probes = probe_points(width, height);
    let finite: Vec<usize> = (0..regs.len())
        .filter(|&k| {
            let w = &regs[k].warp;
            w.homography.0.iter().all(|v| v.is_finite())
                && w.field.as_ref().is_none_or(|f| f.is_consistent())
                && probes.iter().all(|&(x, y)| {
                    let (u, v) = w.apply(x, y);
                    u.is_finite() && v.is_finite()
                })
        })
        .collect();
    let mut keep = finite.clone();
    let corr: Vec<(usize, f64)> = keep.iter().filter_map(|&k| regs[k].stats.map(|s| (k, s.correlation))).collect();
    if corr.len() == keep.len() && !corr.is_empty() {
        let m = median(corr.iter().map(|c| c.1).collect());
        let res = median(keep.iter().filter_map(|&k| regs[k].stats.map(|s| s.residual_px)).collect());
        keep.retain(|&k| {
            let s = regs[k].stats.expect("every kept capture has stats");
            s.correlation >= RIG_MIN_CORRELATION_SHARE * m && s.residual_px <= (3.0 * res).max(0.5)
        });
    }
    if keep.len() >= 3 {
        let med: Vec<(f64, f64)> = probes
            .iter()
            .map(|&(x, y)| {
                let pts: Vec<(f64, f64)> = keep.iter().map(|&k| regs[k].warp.apply(x, y)).collect();
                (median(pts.iter().map(|p| p.0).collect()), median(pts.iter().map(|p| p.1).collect()))
            })
            .collect();
        let dist = |k: usize| -> f64 {
            probes
                .iter()
                .zip(&med)
                .map(|(&(x, y), m)| {
                    let (u, v) = regs[k].warp.apply(x, y);
                    (u - m.0).hypot(v - m.1)
                })
                .fold(0.0, f64::max)
        };
        let d: Vec<f64> = keep.iter().map(|&k| dist(k)).collect();
        let limit = (RIG_OUTLIER_FACTOR * median(d.clone())).max(RIG_OUTLIER_MIN_PX);
        keep = keep.into_iter().zip(d).filter(|(_, d)| *d <= limit).map(|(k, _)| k).collect();
    }
    if keep.is_empty() {
        finite
    } else {
        keep
    }
}

/// A 3x3 grid over the image (corners, edge midpoints, centre).
fn probe_points(width: usize, height: usize) -> Vec<(f64, f64)> {
    let (w, h) = ((width.max(1) - 1) as f64, (height.max(1) - 1) as f64);
    [0.0, 0.5, 1.0].iter().flat_map(|&fy| [0.0, 0.5, 1.0].map(move |fx| (fx * w, fy * h))).collect()
}

/// The rig's warps from several captures, robust to captures whose alignment failed or wandered: per band the
/// captures of [`rig_inliers`]; the homography fitted to the median positions of their homographies at a 3x3 grid
/// of probe points (a median in the image, not of the matrices' entries); the field the node-wise median of
/// theirs (a capture without a field counting as zero) when at least half of them have one. The spread: the
/// largest distance, over the kept captures and the image corners, between a capture's own warp and the median
/// (pixels).
pub fn median_warps(sets: &[Vec<BandRegistration>], width: usize, height: usize) -> (Vec<BandRegistration>, Vec<f64>) {
    let Some(first) = sets.first() else { return (Vec::new(), Vec::new()) };
    let nb = first.len();
    let probes = probe_points(width, height);
    let mut out = Vec::with_capacity(nb);
    let mut spread = Vec::with_capacity(nb);
    for (bi, band) in first.iter().enumerate() {
        let regs: Vec<&BandRegistration> = sets.iter().filter_map(|s| s.get(bi)).collect();
        let keep = rig_inliers(&regs, width, height);
        let kept: Vec<&BandRegistration> = keep.iter().map(|&k| regs[k]).collect();
        match kept.first() {
            // One warp for every capture (the reference band's identity) is kept as it is; without any usable
            // warp the first capture's stands.
            Some(k0) if kept.iter().all(|r| r.warp == k0.warp) => {
                spread.push(0.0);
                out.push(BandRegistration { band: band.band.clone(), warp: k0.warp.clone(), stats: None });
                continue;
            }
            None => {
                spread.push(0.0);
                out.push(BandRegistration { band: band.band.clone(), warp: band.warp.clone(), stats: None });
                continue;
            }
            _ => {}
        }
        let pairs: Vec<((f64, f64), (f64, f64))> = probes
            .iter()
            .map(|&(x, y)| {
                let pts: Vec<(f64, f64)> = kept.iter().map(|r| r.warp.homography.apply(x, y)).collect();
                ((x, y), (median(pts.iter().map(|p| p.0).collect()), median(pts.iter().map(|p| p.1).collect())))
            })
            .collect();
        let h = fit_homography(&pairs).unwrap_or_else(|| {
            let hs: Vec<[f64; 9]> = kept.iter().map(|r| r.warp.homography.normalized().0).collect();
            Homography(std::array::from_fn(|k| median(hs.iter().map(|v| v[k]).collect())))
        });
        let with_field: Vec<&ShiftField> = kept.iter().filter_map(|r| r.warp.field.as_ref()).collect();
        let field = with_field.first().filter(|_| 2 * with_field.len() >= kept.len()).map(|f0| {
            let same = |f: &ShiftField| f.nx == f0.nx && f.ny == f0.ny && f.step == f0.step;
            let d = (0..f0.d.len())
                .map(|n| {
                    [0, 1].map(|c| {
                        median(
                            kept.iter()
                                .map(|r| r.warp.field.as_ref().filter(|f| same(f)).map_or(0.0, |f| f.d[n][c]))
                                .collect(),
                        )
                    })
                })
                .collect();
            ShiftField { d, ..(*f0).clone() }
        });
        let warp = Warp { homography: h, field };
        let corners = [
            (0.0, 0.0),
            (width as f64 - 1.0, 0.0),
            (0.0, height as f64 - 1.0),
            (width as f64 - 1.0, height as f64 - 1.0),
        ];
        let s = kept
            .iter()
            .flat_map(|r| {
                let (w, m) = (&r.warp, &warp);
                corners.iter().map(move |&(x, y)| {
                    let (a, b) = w.apply(x, y);
                    let (c, d) = m.apply(x, y);
                    (a - c).hypot(b - d)
                })
            })
            .fold(0.0, f64::max);
        spread.push(s);
        out.push(BandRegistration { band: band.band.clone(), warp, stats: None });
    }
    (out, spread)
}

/// The largest axis-aligned rectangle (by peeling the border line with most invalid pixels) where `valid`.
fn common_rect(valid: &[bool], w: usize, h: usize) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (0usize, 0usize, w, h);
    loop {
        if x1 <= x0 + 1 || y1 <= y0 + 1 {
            return None;
        }
        let col = |x: usize| (y0..y1).filter(|&y| !valid[y * w + x]).count();
        let row = |y: usize| (x0..x1).filter(|&x| !valid[y * w + x]).count();
        let c = [col(x0), col(x1 - 1), row(y0), row(y1 - 1)];
        let frac = [
            c[0] as f64 / (y1 - y0) as f64,
            c[1] as f64 / (y1 - y0) as f64,
            c[2] as f64 / (x1 - x0) as f64,
            c[3] as f64 / (x1 - x0) as f64,
        ];
        let (i, worst) = frac.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).expect("four sides");
        if *worst == 0.0 {
            return Some((x0, y0, x1, y1));
        }
        match i {
            0 => x0 += 1,
            1 => x1 -= 1,
            2 => y0 += 1,
            _ => y1 -= 1,
        }
    }
}

/// The rectangle of target pixels (x0, y0, x1, y1), end exclusive, where every band's warp lands inside its
/// raw image: computed from the geometry alone, so a flight's common crop is known before any pixel is resampled.
pub fn valid_rect(
    cap: &Capture,
    registration: &[BandRegistration],
    ref_idx: usize,
    undistort: bool,
) -> Option<(usize, usize, usize, usize)> {
    let target = target_for(cap, ref_idx, undistort);
    let (w, h) = (target.width, target.height);
    let mut valid = vec![true; w * h];
    for (b, r) in cap.bands.iter().zip(registration) {
        let lens = lens_of(b, undistort);
        let (bw, bh) = ((b.meta.width - 1) as f64, (b.meta.height - 1) as f64);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if valid[i] {
                    let (sx, sy) = super::lens::source_pixel(&target, lens.as_ref(), &r.warp, x as f64, y as f64);
                    valid[i] = sx >= 0.0 && sy >= 0.0 && sx <= bw && sy <= bh;
                }
            }
        }
    }
    common_rect(&valid, w, h)
}

/// Intersection of rectangles.
pub fn intersect(
    a: (usize, usize, usize, usize),
    b: (usize, usize, usize, usize),
) -> Option<(usize, usize, usize, usize)> {
    let r = (a.0.max(b.0), a.1.max(b.1), a.2.min(b.2), a.3.min(b.3));
    (r.2 > r.0 + 1 && r.3 > r.1 + 1).then_some(r)
}

/// The reference band of the crop as an 8-bit greyscale PNG for SfM tools (COLMAP, ODM, Metashape read it; they do
/// not read multi-band float TIFFs), stretched from its 0.5th to its 99.5th percentile. Same stem and size as the
/// frame, so `import poses` matches the tool's images to the frames.
pub(super) fn write_sfm_png(
    p: &Plane,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    path: &Path,
) -> Result<(), RigError> {
    let mut v: Vec<f32> = Vec::with_capacity((x1 - x0) * (y1 - y0));
    for y in y0..y1 {
        for x in x0..x1 {
            v.push(p.at(x, y));
        }
    }
    // Percentiles of the pixels that hold a value (an uncropped undistortion leaves NaN corners).
    let mut sorted: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if sorted.is_empty() {
        sorted.push(0.0);
    }
    sorted.sort_by(f32::total_cmp);
    let lo = sorted[sorted.len() / 200];
    let hi = sorted[sorted.len() - 1 - sorted.len() / 200].max(lo + f32::EPSILON);
    let bytes: Vec<u8> = v.iter().map(|x| (((x - lo) / (hi - lo)).clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    let img = image::GrayImage::from_raw((x1 - x0) as u32, (y1 - y0) as u32, bytes).expect("size");
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(RigError::io(parent))?;
    }
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| RigError::Output { path: path.to_path_buf(), reason: e.to_string() })
}

/// Resamples every band through its warp, crops to `rect` (the flight's common area) and writes
/// `images/<capture>.tif` under `dir`.
pub fn write_frame(
    cap: &Capture,
    l: &Loaded,
    registration: Vec<BandRegistration>,
    ref_idx: usize,
    undistort: bool,
    rect: (usize, usize, usize, usize),
    dir: &Path,
) -> Result<FrameOut, RigError> {
    let nb = cap.bands.len();
    let target = target_for(cap, ref_idx, undistort);
    let out: Vec<Plane> = cap
        .bands
        .iter()
        .zip(&registration)
        .enumerate()
        .map(|(bi, (b, r))| resample(&l.values[bi], &target, lens_of(b, undistort).as_ref(), &r.warp))
        .collect();
    let (x0, y0, x1, y1) = rect;
    let (cw, ch) = (x1 - x0, y1 - y0);
    let mut data = Vec::with_capacity(cw * ch * nb);
    for y in y0..y1 {
        for x in x0..x1 {
            for p in &out {
                let v = p.at(x, y);
                if !v.is_finite() {
                    return Err(RigError::Capture {
                        capture: cap.key.clone(),
                        reason: format!(
                            "no value at ({x}, {y}) inside the common crop (a band's warp leaves its image)"
                        ),
                    });
                }
                data.push(v);
            }
        }
    }
    write_sfm_png(&out[ref_idx], rect, &dir.join("sfm_images").join(format!("{}.png", cap.name())))?;
    let value_quantiles =
        (0..nb).map(|b| crate::rig::flight_checks::quantiles(data.iter().skip(b).step_by(nb * 7).copied())).collect();
    let file = format!("images/{}.tif", cap.name());
    let path = dir.join(&file);
    write_tiff(&path, cw as u32, ch as u32, nb, TiffData::F32(&data))
        .map_err(|e| RigError::Output { path: path.clone(), reason: e.to_string() })?;
    Ok(FrameOut {
        capture: cap.key.clone(),
        file,
        width: cw,
        height: ch,
        fx: target.f,
        cx: target.cx - x0 as f64,
        cy: target.cy - y0 as f64,
        saturated: l.saturated.clone(),
        registration,
        value_quantiles,
    })
}
