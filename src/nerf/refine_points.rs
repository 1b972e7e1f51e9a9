//! The export's photometric refinement ([`super::refine`]) applied to a run: the training images a batch of points
//! needs, decoded once into per-band f32 planes within a byte budget, and the points refined on every core.
//!
//! Each point brings its own frame (the reference view: the pixel it came from) and the frames whose rendered depth
//! agreed with it in the consistency check (its partners: views that see it unoccluded). Points are refined in
//! groups of one reference frame, so the images a group needs are few and neighbouring; when the next group's
//! frames would pass the budget, every frame it does not need is dropped (a later group may read one again). A
//! point's partners are cut to what the budget holds. Masked pixels (the dataset's masks) take no part. The patch
//! plane is horizontal on aerial layouts (the world's up when the dataset has a CRS, else the normalised frame's
//! +z, which the normalisation levels to the cameras' mean up) and faces the reference camera otherwise.
//!
//! Only bands seen through the frame camera take part (with `rig_cameras`, a band with its own camera pose sees the
//! point elsewhere); a run with none is left unrefined and says so.

use super::error::{NerfError, NerfResult};
use super::refine::{refine, PatchView, RefineOptions};
use super::run::LoadedRun;
use std::collections::HashMap;

/// A point to refine, in the normalised frame.
pub struct RefinePoint {
    pub p: [f64; 3],
    /// Unit direction of the ray that found it (the search line).
    pub dir: [f64; 3],
    /// The frame the ray came from (the reference view).
    pub frame: usize,
    /// Frames that agreed with it (partners).
    pub partners: Vec<u32>,
}

/// What the refinement did to a batch.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefineStats {
    pub points: usize,
    pub moved: usize,
    /// Points the images support that kept the field's position (a best NCC below [`RefineOptions::move_ncc`]).
    pub kept: usize,
    /// Median |shift| of the moved points (normalised units from [`refine_points`], world units in the export's stats).
    pub median_shift: f64,
    /// Why nothing was refined, when nothing could be.
    pub skipped: Option<String>,
}

/// Per-point result: the shift along the ray (normalised units) and the best NCC (NaN: none scored).
pub struct PointResult {
    pub shift: f64,
    pub ncc: f64,
    /// Whether the point moved (see [`super::refine`]).
    pub moved: bool,
    /// Whether the images support a surface at or near the point (`moved` implies it).
    pub supported: bool,
    /// Offset of the best score along the ray whether or not the point moved (normalised units; NaN: unsupported).
    pub peak: f64,
    /// One pixel footprint of the reference view at the point (normalised units).
    pub footprint: f64,
}

impl PointResult {
    fn none() -> Self {
        Self { shift: 0.0, ncc: f64::NAN, moved: false, supported: false, peak: f64::NAN, footprint: f64::NAN }
    }
}

/// Decoded planes of the frames a group needs, bounded by `budget` bytes; kept across calls of [`refine_points`]
/// (the DSM refines block by block).
pub struct FrameStore {
    planes: HashMap<usize, Vec<Vec<f32>>>,
    bytes_per_frame: u64,
    budget: u64,
}

impl FrameStore {
    /// An empty store holding at most `budget` bytes of images.
    pub fn new(budget: u64) -> Self {
        Self { planes: HashMap::new(), bytes_per_frame: 0, budget }
    }

    fn ensure(&mut self, run: &LoadedRun, bands: &[usize], needed: &[usize]) -> NerfResult<()> {
        let over = |n: usize| n as u64 * self.bytes_per_frame > self.budget;
        if over(self.planes.len() + needed.iter().filter(|f| !self.planes.contains_key(f)).count()) {
            self.planes.retain(|f, _| needed.contains(f));
        }
        for &f in needed {
            if let std::collections::hash_map::Entry::Vacant(slot) = self.planes.entry(f) {
                let r = run.ds.read_frame(f)?;
                let masked: Vec<usize> = match &r.mask {
                    Some(m) => m.iter().enumerate().filter(|(_, &v)| v == 0).map(|(i, _)| i).collect(),
                    None => Vec::new(),
                };
                slot.insert(
                    bands
                        .iter()
                        .map(|&b| {
                            let mut plane = r.band_f32(b);
                            for &i in &masked {
                                plane[i] = f32::NAN;
                            }
                            plane
                        })
                        .collect(),
                );
            }
        }
        Ok(())
    }
}

/// Refines `points` in place against the run's training images; returns each point's result and the batch's stats.
pub fn refine_points(
    run: &LoadedRun,
    points: &mut [RefinePoint],
    opts: &RefineOptions,
    store: &mut FrameStore,
) -> NerfResult<(Vec<PointResult>, RefineStats)> {
    let budget_bytes = store.budget;
    let mut stats = RefineStats { points: points.len(), ..Default::default() };
    let mut results: Vec<PointResult> = points.iter().map(|_| PointResult::none()).collect();
    let ds = &run.ds;
    let bands: Vec<usize> = (0..ds.bands.len())
        .filter(|&b| ds.band_camera(b).is_none_or(|bc| ds.frames.iter().all(|f| bc.is_frame_camera(&f.camera))))
        .collect();
    if bands.is_empty() {
        stats.skipped = Some("every band has its own rig camera: no band sees through the frame camera".into());
        return Ok((results, stats));
    }
    if points.is_empty() {
        return Ok((results, stats));
    }
    let (w, h) = (ds.width as u64, ds.height as u64);
    let bytes_per_frame = w * h * bands.len() as u64 * 4;
    let frames_held = (budget_bytes / bytes_per_frame.max(1)) as usize;
    if frames_held < 1 + opts.min_views.max(1) {
        return Err(NerfError::invalid(
            "photometric refinement",
            format!(
                "one image takes {} MiB as f32 and {} are needed at once, over the {} MiB budget (export with \
                 --no-refine)",
                bytes_per_frame >> 20,
                1 + opts.min_views.max(1),
                budget_bytes >> 20
            ),
        ));
    }
    for p in points.iter_mut() {
        p.partners.truncate(frames_held - 1);
    }
    let up = up_axis(run);
    let poses = normalised_poses(run);
    let cams: Vec<crate::data::Camera> = ds.frames.iter().map(|f| f.camera).collect();
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by_key(|&i| points[i].frame);
    store.bytes_per_frame = bytes_per_frame;
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let mut start = 0;
    while start < order.len() {
        let frame = points[order[start]].frame;
        let mut end = start;
        let mut needed = vec![frame];
        // A group: this reference frame's points, cut where the frames they need would pass the budget.
        while end < order.len() && points[order[end]].frame == frame {
            let mut more = needed.clone();
            for &f in &points[order[end]].partners {
                if !more.contains(&(f as usize)) {
                    more.push(f as usize);
                }
            }
            if more.len() as u64 * bytes_per_frame > budget_bytes && end > start {
                break;
            }
            needed = more;
            end += 1;
        }
        store.ensure(run, &bands, &needed)?;
        let group = &order[start..end];
        let chunk = group.len().div_ceil(threads).max(1);
        let pts = &*points;
        let store_ref = &*store;
        let poses_ref = &poses;
        let cams = &cams;
        let out: Vec<Vec<(usize, PointResult)>> = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .chunks(chunk)
                .map(|ids| {
                    s.spawn(move || {
                        ids.iter()
                            .map(|&i| (i, refine_one(cams, &pts[i], up, poses_ref, store_ref, opts)))
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().expect("refinement thread panicked")).collect()
        });
        for (i, r) in out.into_iter().flatten() {
            results[i] = r;
        }
        start = end;
    }
    let mut shifts = Vec::new();
    for (p, r) in points.iter_mut().zip(&results) {
        if r.moved {
            p.p = [0, 1, 2].map(|k| p.p[k] + r.shift * p.dir[k]);
            shifts.push(r.shift.abs());
        }
    }
    stats.moved = shifts.len();
    stats.kept = results.iter().filter(|r| r.supported && !r.moved).count();
    if !shifts.is_empty() {
        shifts.sort_by(f64::total_cmp);
        stats.median_shift = shifts[shifts.len() / 2];
    }
    Ok((results, stats))
}

/// One pixel footprint of `cam` (centre `origin`) at `p`: distance over the mean focal length.
fn footprint(cam: &crate::data::Camera, origin: [f64; 3], p: [f64; 3]) -> f64 {
    (glam::DVec3::from(p) - glam::DVec3::from(origin)).length() / (0.5 * (cam.fx + cam.fy))
}

/// Every frame's camera centre and camera-to-world rotation rows (as [`project_point_subpixel`] takes them) in the
/// normalised frame, by frame index.
///
/// [`project_point_subpixel`]: crate::data::camera::project_point_subpixel
pub fn normalised_poses(run: &LoadedRun) -> Vec<FramePose> {
    (run.ds.frames.iter())
        .map(|f| {
            let m = run.transform.pose_to_normalized(&f.c2w);
            ([m[0][3], m[1][3], m[2][3]], [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2]]))
        })
        .collect()
}

/// A frame's camera centre and camera-to-world rotation rows.
pub type FramePose = ([f64; 3], [[f64; 3]; 3]);

/// The up direction in the normalised frame on aerial layouts (the world's +z when the dataset has a CRS, else the
/// normalised frame's +z, levelled to the cameras' mean up); None for other layouts.
fn up_axis(run: &LoadedRun) -> Option<[f64; 3]> {
    match (run.ds.aerial_layout(), run.ds.crs.is_some()) {
        (true, true) => Some((run.transform.rotation() * glam::DVec3::Z).normalize().to_array()),
        (true, false) => Some([0.0, 0.0, 1.0]),
        (false, _) => None,
    }
}

fn refine_one(
    cams: &[crate::data::Camera],
    pt: &RefinePoint,
    up: Option<[f64; 3]>,
    poses: &[FramePose],
    store: &FrameStore,
    opts: &RefineOptions,
) -> PointResult {
    let view = |f: usize| {
        let (origin, rot) = poses[f];
        let planes = store.planes.get(&f)?.iter().map(|p| p.as_slice()).collect();
        Some(PatchView { origin, rot, cam: &cams[f], planes })
    };
    let mut views = Vec::with_capacity(1 + pt.partners.len());
    let Some(reference) = view(pt.frame) else {
        return PointResult::none();
    };
    let footprint = footprint(&cams[pt.frame], reference.origin, pt.p);
    views.push(reference);
    views.extend(pt.partners.iter().filter_map(|&f| view(f as usize)));
    // Horizontal on aerial layouts: the density field's normals, tried instead, follow its bumps (on the campus the
    // cloud's median distance went from 0.034 to 0.14-0.16 m; docs/geometry.md).
    let n = up.unwrap_or([-pt.dir[0], -pt.dir[1], -pt.dir[2]]);
    let r = refine(pt.p, pt.dir, n, footprint, &views, opts);
    PointResult {
        shift: if r.moved { r.s } else { 0.0 },
        ncc: r.ncc,
        moved: r.moved,
        supported: r.supported,
        peak: r.peak,
        footprint,
    }
}
