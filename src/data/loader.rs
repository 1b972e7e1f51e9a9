//! `Dataset`: a `transforms.json` folder turned into sorted frames with poses, intrinsics, image sources,
//! splits and bands; images are decoded on demand by [`Dataset::read_frame`] into compact [`Raster`]s.
//!
//! Loading checks everything that needs no pixel decode for every frame (keys, values, orthonormal
//! rotations, focal lengths, file existence, duplicate names, empty train split) and decodes the first
//! frame to learn the image size, sample type and, when `bands` is absent, the band identity (XMP of rig
//! files, else RGB for 3-channel images). Pixel-level checks (size, band count, NaN/Inf) happen per image
//! in `read_frame` and for all images in `check::check_dataset`. Files are only ever opened for reading.

use std::path::{Path, PathBuf};

use super::camera::Camera;
use super::error::{DataError, FrameRef};
use super::pose::{from_dmat4, normalize_poses, rigid_inverse, to_dmat4, Mat4, PoseTransform};
use super::raster::Alpha;
use super::raster::{BandScale, Raster, SampleType, Samples, MAX_MODEL_VALUE};
use super::reader::{read_image_file, AlphaChannel, DecodedImage};
use super::split::{assign_splits, normalize_name, Split, SplitMethod};
use super::transforms::parse_transforms;
pub use super::transforms::Band;

/// Options for [`load_dataset`].
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Mask NaN/Inf pixels out instead of rejecting the image.
    pub mask_non_finite: bool,
    /// How [`Dataset::pose_transform`] normalises the poses.
    pub normalization: super::pose::PoseNormalization,
    /// Leave frames with an outlying camera centre out (split `unused`, listed in `Dataset::dropped_outliers`)
    /// instead of refusing the dataset ([`super::outliers`]).
    pub drop_outliers: bool,
    /// What an image's alpha channel is composited over when the frame is read ([`AlphaBackground`]).
    pub alpha_background: AlphaBackground,
}

/// What the ground truth of an image with an alpha channel is composited over, as nerfstudio's
/// `RGBRenderer.blend_background` does it: `gt = c·α + bg·(1 − α)` in every band (model values, after the black
/// level and pixel scale).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum AlphaBackground {
    /// Black (0): the default, and the model backgrounds `last_sample` (nerfstudio does not blend the ground truth
    /// with the last sample) and `random` outside training.
    #[default]
    Black,
    /// White (1): the model background `white`.
    White,
    /// The model background `random` in training: nerfstudio blends the ground truth with each ray's random colour
    /// in the loss, which msnerf's loss does not do, so a frame with alpha is refused by name.
    Refuse,
}

// A model's background chooses among these (`nerf::config::Background::alpha_background`): the data layer does not
// read the model's configuration.

/// Where a frame's pixels come from.
#[derive(Debug, Clone, PartialEq)]
pub enum ImageSource {
    /// One file with all bands.
    File(PathBuf),
    /// One single-band file per band, in band order.
    BandFiles(Vec<PathBuf>),
}

/// One frame, after sorting by file name.
#[derive(Debug, Clone)]
pub struct Frame {
    /// `file_path` (or first band file) as written; the sort key.
    pub name: String,
    /// Index of the frame in `transforms.json` as written.
    pub index_in_file: usize,
    /// Camera-to-world, OpenGL axes, the dataset's own world units.
    pub c2w: Mat4,
    pub camera: Camera,
    pub image: ImageSource,
    pub mask: Option<PathBuf>,
    pub depth: Option<PathBuf>,
    pub split: Split,
}

impl Frame {
    pub fn frame_ref(&self) -> FrameRef {
        FrameRef { index: self.index_in_file, name: self.name.clone() }
    }
}

/// A loaded dataset (no pixels held; see [`Dataset::read_frame`]).
#[derive(Debug, Clone)]
pub struct Dataset {
    pub root: PathBuf,
    pub transforms_path: PathBuf,
    /// Sorted by file name.
    pub frames: Vec<Frame>,
    pub bands: Vec<Band>,
    pub width: u32,
    pub height: u32,
    pub sample_type: SampleType,
    pub split_method: SplitMethod,
    pub pixel_scale: Option<f64>,
    pub black_level: Option<f64>,
    /// Metres per stored depth unit.
    pub depth_unit_scale_factor: f64,
    /// `depth_type`: true for `z`, false for `ray_distance`.
    pub depth_is_z: bool,
    /// `sparse_points_path`: SfM-like sparse points with the frames that observed them ([`super::sparse_points`]).
    pub sparse_points_path: Option<PathBuf>,
    pub options: LoadOptions,
    /// The inverse of nerfstudio's `applied_transform` when the file had one: already applied to every pose, and
    /// applied to the sparse points as they are read, so the dataset's world is COLMAP's (or the georeferenced) frame.
    pub applied_transform_undone: Option<Mat4>,
    /// `crs`: the projected CRS of the world frame (outputs with coordinates carry it).
    pub crs: Option<crate::geo::Crs>,
    /// Frames left out for an outlying camera centre (`LoadOptions::drop_outliers`).
    pub dropped_outliers: Vec<String>,
    /// Set by [`Dataset::select_bands`]: the dataset then reads and reports only these bands of its files.
    pub band_selection: Option<BandSelection>,
    /// [`Dataset::pose_transform`] and whether it is the aerial fit, computed once (the fit looks at pairs of
    /// cameras).
    pub transform_cache: std::sync::OnceLock<(PoseTransform, bool)>,
    /// Whether the first frame's file has an alpha channel (composited as `options.alpha_background` says).
    pub has_alpha: bool,
    /// `rig_cameras`: one camera per band of the files, in file band order ([`super::rig_cameras`]); read through
    /// [`Dataset::band_camera`], which follows a band selection.
    pub rig: Option<super::rig_cameras::RigCameras>,
}

/// A subset of a dataset's bands (`msnerf train --bands`, sweep axis `bands`): the indices kept, in order, into
/// `all`, the bands the files hold.
#[derive(Debug, Clone, PartialEq)]
pub struct BandSelection {
    pub indices: Vec<usize>,
    pub all: Vec<Band>,
}

fn frame_of(f: &Frame) -> FrameRef {
    f.frame_ref()
}

/// Loads `dir/transforms.json` (or `dir` itself when it is a file). All errors are collected.
pub fn load_dataset(dir: &Path, options: &LoadOptions) -> Result<Dataset, DataError> {
    let tpath = if dir.is_file() { dir.to_path_buf() } else { dir.join("transforms.json") };
    let root = tpath.parent().unwrap_or(Path::new(".")).to_path_buf();
    let raw = parse_transforms(&tpath)?;
    let mut errors = Vec::new();

    // Sort by file name and reject duplicates.
    let mut raw_frames = raw.frames;
    raw_frames.sort_by(|a, b| a.name.cmp(&b.name).then(a.index.cmp(&b.index)));
    let mut seen = std::collections::HashMap::new();
    for f in &raw_frames {
        let files: Vec<String> = match (&f.file_path, &f.band_files) {
            (Some(_), _) => vec![normalize_name(&f.name)],
            (None, Some(b)) => b.iter().map(|p| p.to_string_lossy().into_owned()).collect(),
            _ => vec![],
        };
        for n in files {
            if let Some(prev) = seen.insert(n.clone(), f.index) {
                errors.push(DataError::DuplicateFileName {
                    path: tpath.clone(),
                    key: if f.file_path.is_some() { "file_path" } else { "band_files" }.into(),
                    frame: Some(FrameRef { index: f.index, name: f.name.clone() }),
                    name: format!("{n} (also in frame {prev})"),
                });
            }
        }
    }
    let names: Vec<String> = raw_frames.iter().map(|f| f.name.clone()).collect();
    let per_frame: Vec<Option<Split>> = raw_frames.iter().map(|f| f.split).collect();
    let (splits, split_method) = assign_splits(&names, &per_frame, &raw.lists);
    if !splits.contains(&Split::Train) {
        errors.push(DataError::EmptyTrainSplit {
            path: tpath.clone(),
            key: match split_method {
                SplitMethod::Filenames => "train_filenames",
                SplitMethod::PerFrame => "split",
                SplitMethod::Interval => "frames",
            }
            .into(),
        });
    }

    let undo = raw.applied_transform.map(|a| from_dmat4(&rigid_inverse(&to_dmat4(&a))));
    let mut frames = Vec::with_capacity(raw_frames.len());
    for (f, split) in raw_frames.into_iter().zip(splits) {
        let fr = FrameRef { index: f.index, name: f.name.clone() };
        let image = match (f.file_path, f.band_files) {
            (Some(p), _) => ImageSource::File(p),
            (None, Some(b)) => ImageSource::BandFiles(b),
            (None, None) => unreachable!("parse_frame rejects frames without images"),
        };
        let mut check = |p: &Path, key: &str| {
            if !p.is_file() {
                errors.push(DataError::MissingFile {
                    path: p.to_path_buf(),
                    key: key.into(),
                    frame: Some(fr.clone()),
                    reason: "no such file".into(),
                });
            }
        };
        match &image {
            ImageSource::File(p) => check(p, "file_path"),
            ImageSource::BandFiles(b) => b.iter().for_each(|p| check(p, "band_files")),
        }
        if let Some(m) = &f.mask_path {
            check(m, "mask_path");
        }
        if let Some(d) = &f.depth_path {
            check(d, "depth_file_path");
        }
        frames.push(Frame {
            name: f.name,
            index_in_file: f.index,
            c2w: undo.as_ref().map_or(f.c2w, |u| from_dmat4(&(to_dmat4(u) * to_dmat4(&f.c2w)))),
            camera: f.camera,
            image,
            mask: f.mask_path,
            depth: f.depth_path,
            split,
        });
    }
    // Implausible camera centres: refused by name, or left out when asked.
    let mut dropped_outliers = Vec::new();
    for o in super::outliers::outlier_cameras(&frames) {
        let f = &mut frames[o.frame];
        if options.drop_outliers {
            log::warn!(
                "{}: left out: camera centre {:.3e} from the others' median ({:.3e} median distance)",
                f.name,
                o.distance,
                o.spread
            );
            f.split = Split::Unused;
            dropped_outliers.push(f.name.clone());
        } else {
            errors.push(DataError::OutlierCamera {
                path: tpath.clone(),
                frame: Some(frame_of(f)),
                distance: o.distance,
                spread: o.spread,
            });
        }
    }
    if !dropped_outliers.is_empty() && !frames.iter().any(|f| f.split == Split::Train) {
        errors.push(DataError::EmptyTrainSplit {
            path: tpath.clone(),
            key: "frames (after dropping outlying cameras)".into(),
        });
    }
    // One image size for the whole dataset.
    if let Some(f0) = frames.first() {
        for f in &frames[1..] {
            if (f.camera.width, f.camera.height) != (f0.camera.width, f0.camera.height) {
                errors.push(DataError::InvalidValue {
                    path: tpath.clone(),
                    key: "w".into(),
                    frame: Some(frame_of(f)),
                    reason: format!(
                        "all frames must share one image size: {}x{} here, {}x{} in {}",
                        f.camera.width, f.camera.height, f0.camera.width, f0.camera.height, f0.name
                    ),
                });
                break;
            }
        }
    }
    if let Some(e) = DataError::from_list(errors) {
        return Err(e);
    }
    let (width, height) = (frames[0].camera.width, frames[0].camera.height);
    let mut ds = Dataset {
        root,
        transforms_path: tpath.clone(),
        frames,
        bands: raw.bands.clone().unwrap_or_default(),
        width,
        height,
        sample_type: SampleType::F32,
        split_method,
        pixel_scale: raw.pixel_scale,
        black_level: raw.black_level,
        depth_unit_scale_factor: raw.depth_unit_scale_factor,
        depth_is_z: raw.depth_is_z,
        sparse_points_path: raw.sparse_points.clone(),
        options: options.clone(),
        applied_transform_undone: undo,
        crs: raw.crs.clone(),
        dropped_outliers,
        band_selection: None,
        transform_cache: Default::default(),
        has_alpha: false,
        rig: None,
    };
    // Probe the first frame: sample type, and band identity when the header does not name the bands.
    let probe = ds.decode_sources(0)?;
    ds.sample_type = probe[0].raster.sample_type();
    ds.has_alpha = matches!(ds.frames[0].image, ImageSource::File(_)) && colour_alpha(&probe[0]).is_some();
    if raw.bands.is_none() {
        ds.bands = infer_bands(&ds, &probe)?;
    }
    if let Some(r) = &raw.rig_cameras {
        let names: Vec<String> = ds.bands.iter().map(|b| b.name.clone()).collect();
        let rig = r.resolve(&names, width, height).map_err(|(key, reason)| DataError::InvalidValue {
            path: tpath.clone(),
            key,
            frame: None,
            reason,
        })?;
        ds.rig = Some(rig);
    }
    Ok(ds)
}

fn infer_bands(ds: &Dataset, probe: &[DecodedImage]) -> Result<Vec<Band>, DataError> {
    let f0 = &ds.frames[0];
    let band = |name: String, c: Option<f64>, w: Option<f64>| Band {
        name,
        center_nm: c,
        fwhm_nm: w,
        pixel_scale: None,
        black_level: None,
    };
    match &f0.image {
        ImageSource::BandFiles(files) => {
            let mut out = Vec::new();
            for (i, (d, p)) in probe.iter().zip(files).enumerate() {
                let x = d.meta.xmp.clone().unwrap_or_default();
                let Some(name) = x.name.or_else(|| x.center_nm.map(|c| format!("{c:.0}nm"))) else {
                    return Err(DataError::MissingKey {
                        path: ds.transforms_path.clone(),
                        key: "bands".into(),
                        frame: Some(FrameRef {
                            index: f0.index_in_file,
                            name: format!("band file {i}: {}", p.display()),
                        }),
                    });
                };
                out.push(band(name, x.center_nm, x.fwhm_nm));
            }
            Ok(out)
        }
        ImageSource::File(p) => {
            let d = &probe[0];
            let alpha = colour_alpha(d).map(|a| a.index);
            let n = d.raster.bands - usize::from(alpha.is_some());
            if !d.meta.channel_names.is_empty() && n != 3 {
                let names = d.meta.channel_names.iter().enumerate().filter(|&(i, _)| Some(i) != alpha);
                return Ok(names.map(|(_, n)| band(n.clone(), None, None)).collect());
            }
            if n == 3 || n == 4 {
                return Ok(["red", "green", "blue"].iter().map(|s| band(s.to_string(), None, None)).collect());
            }
            if n == 1 {
                if let Some(x) = d.meta.xmp.clone().filter(|x| x.name.is_some()) {
                    return Ok(vec![band(x.name.unwrap_or_default(), x.center_nm, x.fwhm_nm)]);
                }
            }
            Err(DataError::MissingKey {
                path: ds.transforms_path.clone(),
                key: "bands".into(),
                frame: Some(FrameRef { index: f0.index_in_file, name: format!("{} has {n} channels", p.display()) }),
            })
        }
    }
}

/// Whether an EXR channel name matches a band name (case-insensitive; `layer.R` matches `R`; `red`/`r`).
fn channel_matches(channel: &str, band: &str) -> bool {
    let c = channel.rsplit('.').next().unwrap_or(channel).to_ascii_lowercase();
    let b = band.to_ascii_lowercase();
    if c == b || channel.eq_ignore_ascii_case(band) {
        return true;
    }
    let alias = |s: &str| match s {
        "r" | "red" => "red",
        "g" | "green" => "green",
        "b" | "blue" => "blue",
        _ => "",
    };
    !alias(&c).is_empty() && alias(&c) == alias(&b)
}

impl Dataset {
    pub fn n_bands(&self) -> usize {
        self.bands.len()
    }

    /// Keeps only the bands at `indices` (0-based, in the order given, no repeats) of the bands the files hold:
    /// `bands`, `n_bands` and every raster [`Dataset::read_frame`] returns have just those from then on. Selecting
    /// again picks from all the file bands, not from the previous selection.
    pub fn select_bands(&mut self, indices: &[usize]) -> Result<(), DataError> {
        let all = self.file_bands().to_vec();
        let bad = |reason: String| DataError::InvalidValue {
            path: self.transforms_path.clone(),
            key: "bands".into(),
            frame: None,
            reason,
        };
        if indices.is_empty() {
            return Err(bad("the band selection is empty".into()));
        }
        if let Some(&i) = indices.iter().find(|&&i| i >= all.len()) {
            return Err(bad(format!(
                "band index {i} is out of range: the dataset has {} bands (0..{})",
                all.len(),
                all.len()
            )));
        }
        if let Some((k, &i)) = indices.iter().enumerate().find(|(k, i)| indices[..*k].contains(i)) {
            return Err(bad(format!("band index {i} is selected twice (position {k})")));
        }
        self.bands = indices.iter().map(|&i| all[i].clone()).collect();
        self.band_selection = Some(BandSelection { indices: indices.to_vec(), all });
        Ok(())
    }

    /// The camera of (selected) band `b` when the dataset has `rig_cameras`.
    pub fn band_camera(&self, b: usize) -> Option<&super::rig_cameras::BandCamera> {
        let file_band = self.band_selection.as_ref().map_or(b, |s| s.indices[b]);
        self.rig.as_ref().map(|r| &r.cameras[file_band])
    }

    /// The bands the image files hold (all of them, whatever [`Dataset::select_bands`] kept).
    pub fn file_bands(&self) -> &[Band] {
        self.band_selection.as_ref().map_or(&self.bands, |s| &s.all)
    }

    /// Bytes one image takes in memory (samples only).
    pub fn image_bytes(&self) -> u64 {
        self.width as u64 * self.height as u64 * self.bands.len() as u64 * self.sample_type.bytes() as u64
    }

    /// Bytes one image takes in memory including its mask plane, if the frame has one, and its alpha plane, if
    /// the first frame had one.
    pub fn frame_bytes(&self, i: usize) -> u64 {
        let px = self.width as u64 * self.height as u64;
        let mask = if self.frames[i].mask.is_some() { px } else { 0 };
        let alpha = if self.has_alpha { px * self.sample_type.bytes() as u64 } else { 0 };
        self.image_bytes() + mask + alpha
    }

    /// Indices of the frames in a split.
    pub fn split_indices(&self, split: Split) -> Vec<usize> {
        (0..self.frames.len()).filter(|&i| self.frames[i].split == split).collect()
    }

    /// Refuses a dataset whose used cameras all have one centre (a rig import without GPS writes such placeholder
    /// poses until SfM replaces them): normalisation would divide by zero or by rounding noise. Training checks
    /// this; tools that run before SfM (`dataset register`, `sfm`) do not need poses.
    pub fn check_distinct_centres(&self) -> Result<(), DataError> {
        let used = || self.frames.iter().filter(|f| f.split != Split::Unused);
        match super::outliers::coincident_centres(used()) {
            None => Ok(()),
            Some((reach, magnitude)) => Err(DataError::InvalidValue {
                path: self.transforms_path.clone(),
                key: "transform_matrix".into(),
                frame: None,
                reason: format!(
                    "all {} cameras have one centre (they lie within {reach:.1e} of each other at coordinates up to \
                     {magnitude:.1e}): the scene's scale is undefined. Placeholder poses? Import poses from SfM \
                     (`msnerf import poses`) or run it (`msnerf sfm`) first",
                    used().count()
                ),
            }),
        }
    }

    /// The pose normalisation over all frames (nerfstudio normalises before splitting), as
    /// `options.normalization` asks; `aerial` on a layout that is not aerial falls back to `poses`, with a warning.
    pub fn pose_transform(&self) -> PoseTransform {
        self.transform_cache.get_or_init(|| self.compute_pose_transform()).0
    }

    /// Whether [`Dataset::pose_transform`] is the aerial fit: then the unit cube is the region of interest (the
    /// ground the cameras see, 0.5 of its half-size below it and 1.5 above), which the point-cloud export crops to.
    pub fn aerial_normalization(&self) -> bool {
        self.transform_cache.get_or_init(|| self.compute_pose_transform()).1
    }

    /// Whether the cameras fly over a scene: they look down and their axes meet (what `auto` needs for `aerial`),
    /// whichever normalisation the options ask for.
    pub fn aerial_layout(&self) -> bool {
        self.aerial_normalization() || self.aerial_fit().is_ok()
    }

    /// The frames whose poses define the normalisation: all but those dropped as outliers.
    fn posed_frames(&self) -> impl Iterator<Item = &Frame> {
        self.frames.iter().filter(|f| !self.dropped_outliers.contains(&f.name))
    }

    fn aerial_fit(&self) -> Result<PoseTransform, super::aerial::NotAerial> {
        let frames: Vec<(Mat4, super::camera::Camera)> = self.posed_frames().map(|f| (f.c2w, f.camera)).collect();
        super::aerial::normalize_poses_aerial(&frames)
    }

    fn compute_pose_transform(&self) -> (PoseTransform, bool) {
        use super::pose::PoseNormalization;
        let poses: Vec<Mat4> = self.posed_frames().map(|f| f.c2w).collect();
        if self.options.normalization == PoseNormalization::Poses {
            return (normalize_poses(&poses), false);
        }
        match self.aerial_fit() {
            Ok(t) => (t, true),
            Err(why) => {
                if self.options.normalization == PoseNormalization::Aerial {
                    log::warn!("{}: aerial pose normalisation: {why}; using `poses`", self.transforms_path.display());
                }
                (normalize_poses(&poses), false)
            }
        }
    }

    fn max_decode_bytes(&self) -> usize {
        // The expected image at 4 bytes a sample plus slack; bounds what a corrupt header can allocate.
        let px = self.width as usize * self.height as usize;
        (px * self.file_bands().len().max(4) * 4).saturating_mul(2).max(1 << 24)
    }

    fn decode_sources(&self, i: usize) -> Result<Vec<DecodedImage>, DataError> {
        let f = &self.frames[i];
        let max = self.max_decode_bytes();
        let files: Vec<(&PathBuf, &str)> = match &f.image {
            ImageSource::File(p) => vec![(p, "file_path")],
            ImageSource::BandFiles(b) => b.iter().map(|p| (p, "band_files")).collect(),
        };
        let mut out = Vec::new();
        for (p, key) in files {
            let d = read_image_file(p, max).map_err(|reason| DataError::Decode {
                path: p.clone(),
                frame: Some(frame_of(f)),
                reason,
            })?;
            if (d.raster.width, d.raster.height) != (self.width, self.height) {
                return Err(DataError::ImageSize {
                    path: p.clone(),
                    key: key.into(),
                    frame: Some(frame_of(f)),
                    expected: (self.width, self.height),
                    found: (d.raster.width, d.raster.height),
                });
            }
            out.push(d);
        }
        Ok(out)
    }

    /// Decodes frame `i` into a compact raster with band scaling, mask and NaN/Inf handling.
    pub fn read_frame(&self, i: usize) -> Result<Raster, DataError> {
        let raster = self.read_file_bands(i)?;
        Ok(match &self.band_selection {
            Some(sel) => {
                let mut r = select_channels(&raster, &sel.indices);
                r.scaling = sel.indices.iter().map(|&b| raster.scaling[b]).collect();
                r.mask = raster.mask;
                r.alpha = raster.alpha;
                r
            }
            None => raster,
        })
    }

    /// [`Dataset::read_frame`] with every band the files hold.
    fn read_file_bands(&self, i: usize) -> Result<Raster, DataError> {
        let f = &self.frames[i];
        let nb = self.file_bands().len();
        let decoded = self.decode_sources(i)?;
        let (mut raster, file_black) = match &f.image {
            ImageSource::File(p) => {
                let d = decoded.into_iter().next().expect("one file");
                let black = vec![d.meta.black_level; nb];
                (self.arrange_channels(d, p, f)?, black)
            }
            ImageSource::BandFiles(files) => self.stack_bands(decoded, files, f)?,
        };
        if raster.sample_type() != self.sample_type {
            return Err(DataError::Decode {
                path: self.image_path(i).to_path_buf(),
                frame: Some(frame_of(f)),
                reason: format!(
                    "sample type {:?} differs from the first frame's {:?}",
                    raster.sample_type(),
                    self.sample_type
                ),
            });
        }
        raster.scaling = (0..nb).map(|b| self.band_scale(b, file_black.get(b).copied().flatten())).collect();
        if let Some(mp) = &f.mask {
            raster.mask = Some(self.read_mask(mp, f)?);
        }
        if self.sample_type.is_integer() {
            // Integer data's model values are bounded by its scaling: a degenerate `pixel_scale` or `black_level`
            // is refused by name. The type's whole range is checked first; only where that bound fails (12-bit
            // data in a 32-bit container) are the stored values themselves read.
            let full = self.sample_type.default_scale();
            for (b, sc) in raster.scaling.iter().enumerate() {
                let mut e = sc.extreme(full);
                if !plausible(e) {
                    e = sc.extreme(raster.samples.max_raw());
                }
                if !plausible(e) {
                    return Err(DataError::InvalidValue {
                        path: self.transforms_path.clone(),
                        key: "pixel_scale".into(),
                        frame: Some(frame_of(f)),
                        reason: format!(
                            "band {b} (`{}`): stored values map to {e:e} ((value - black_level {:e}) / \
                             pixel_scale {:e}), beyond ±1e6: check pixel_scale and black_level",
                            self.file_bands()[b].name,
                            sc.black,
                            sc.scale
                        ),
                    });
                }
            }
        }
        // Pixels the mask already leaves out (`mask_path`) are not checked: a nodata border under a mask trains.
        let check = raster.samples.value_check(nb, raster.mask.as_deref(), MAX_MODEL_VALUE as f32);
        if check.non_finite > 0 || check.beyond > 0 {
            if !self.options.mask_non_finite {
                let (path, frame) = (self.image_path(i).to_path_buf(), Some(frame_of(f)));
                return Err(if check.non_finite > 0 {
                    DataError::NonFinite { path, frame, count: check.non_finite }
                } else {
                    DataError::OutOfRange { path, frame, count: check.beyond, extreme: check.extreme }
                });
            }
            let px = (self.width * self.height) as usize;
            let mut m = raster.mask.take().unwrap_or_else(|| vec![1; px]);
            for (p, mv) in m.iter_mut().enumerate() {
                if (0..nb).any(|b| !plausible(raster.samples.raw(p * nb + b))) {
                    *mv = 0;
                }
            }
            raster.mask = Some(m);
        }
        Ok(raster)
    }

    /// The main image path of frame `i` (first band file for rigs).
    pub fn image_path(&self, i: usize) -> &Path {
        match &self.frames[i].image {
            ImageSource::File(p) => p,
            ImageSource::BandFiles(b) => &b[0],
        }
    }

    /// Scaling of band `b`: per-band, then top-level, then the file's own black level.
    pub fn band_scale(&self, b: usize, file_black: Option<f64>) -> BandScale {
        if !self.sample_type.is_integer() {
            return BandScale::IDENTITY;
        }
        let band = &self.file_bands()[b];
        BandScale {
            black: band.black_level.or(self.black_level).or(file_black).unwrap_or(0.0),
            scale: band.pixel_scale.or(self.pixel_scale).unwrap_or(self.sample_type.default_scale()),
        }
    }

    /// The file's colour channels in band order, with its alpha channel (if any) taken out and attached as the
    /// raster's [`Alpha`].
    fn arrange_channels(&self, d: DecodedImage, p: &Path, f: &Frame) -> Result<Raster, DataError> {
        let Some(a) = colour_alpha(&d) else { return self.arrange_colour(d, p, f) };
        let background = match self.options.alpha_background {
            AlphaBackground::Black => 0.0,
            AlphaBackground::White => 1.0,
            AlphaBackground::Refuse => {
                return Err(DataError::InvalidValue {
                    path: p.to_path_buf(),
                    key: "rendering.background".into(),
                    frame: Some(frame_of(f)),
                    reason: "the image has an alpha channel and the model trains with the `random` background \
                             (rendering.background or rendering.random_background_steps): nerfstudio blends such \
                             ground truth with each ray's random colour in the loss, which msnerf does not; use \
                             background black, white or last_sample without the warm-up, or remove the alpha channel"
                        .into(),
                })
            }
        };
        let n = d.raster.bands;
        let px = d.raster.width as usize * d.raster.height as usize;
        let mut alpha = Samples::zeros(d.raster.sample_type(), px);
        for q in 0..px {
            alpha.copy_from(q, &d.raster.samples, q * n + a.index);
        }
        let colour: Vec<usize> = (0..n).filter(|&c| c != a.index).collect();
        let mut meta = d.meta;
        if !meta.channel_names.is_empty() {
            meta.channel_names.remove(a.index);
        }
        meta.alpha = None;
        let d = DecodedImage { raster: select_channels(&d.raster, &colour), meta };
        let mut r = self.arrange_colour(d, p, f)?;
        r.alpha = Some(Alpha { samples: alpha, associated: a.associated, background });
        Ok(r)
    }

    fn arrange_colour(&self, d: DecodedImage, p: &Path, f: &Frame) -> Result<Raster, DataError> {
        let nb = self.file_bands().len();
        let r = d.raster;
        let names = &d.meta.channel_names;
        // EXR: match channels to bands by name when every band finds one.
        if !names.is_empty() {
            let idx: Option<Vec<usize>> =
                self.file_bands().iter().map(|b| names.iter().position(|c| channel_matches(c, &b.name))).collect();
            let order: Vec<usize> = match idx {
                Some(v) => v,
                None if r.bands == nb => (0..nb).collect(),
                None => return Err(self.band_count_err(p, f, r.bands)),
            };
            return Ok(select_channels(&r, &order));
        }
        match (r.bands, nb) {
            (a, b) if a == b => Ok(r),
            (4, 3) | (2, 1) => Ok(select_channels(&r, &[0, 1, 2][..nb])),
            (1, 3) if matches!(r.sample_type(), SampleType::U8 | SampleType::U16) => {
                Ok(select_channels(&r, &[0, 0, 0]))
            }
            (a, _) => Err(self.band_count_err(p, f, a)),
        }
    }

    fn band_count_err(&self, p: &Path, f: &Frame, found: usize) -> DataError {
        DataError::BandCount {
            path: p.to_path_buf(),
            key: if matches!(f.image, ImageSource::File(_)) { "file_path" } else { "band_files" }.into(),
            frame: Some(frame_of(f)),
            expected: self.file_bands().len(),
            found,
        }
    }

    /// Interleaves single-band files. A file whose XMP `BandName` names another band goes to that band's
    /// slot (rigs are keyed on band identity, not on the file suffix).
    fn stack_bands(
        &self,
        decoded: Vec<DecodedImage>,
        files: &[PathBuf],
        f: &Frame,
    ) -> Result<(Raster, Vec<Option<f64>>), DataError> {
        let nb = self.file_bands().len();
        if files.len() != nb {
            return Err(DataError::BandCount {
                path: self.transforms_path.clone(),
                key: "band_files".into(),
                frame: Some(frame_of(f)),
                expected: nb,
                found: files.len(),
            });
        }
        let mut slot: Vec<usize> = (0..nb).collect();
        let by_name: Vec<Option<usize>> = decoded
            .iter()
            .map(|d| {
                let n = d.meta.xmp.as_ref()?.name.as_ref()?;
                self.file_bands().iter().position(|b| b.name.eq_ignore_ascii_case(n))
            })
            .collect();
        let mut used = vec![false; nb];
        if by_name.iter().all(|x| x.is_some()) {
            let s: Vec<usize> = by_name.iter().map(|x| x.expect("checked")).collect();
            s.iter().for_each(|&x| used[x] = true);
            if used.iter().all(|&u| u) {
                slot = s;
            }
        }
        let px = (self.width * self.height) as usize;
        let ty = decoded[0].raster.sample_type();
        let mut out = Samples::zeros(ty, px * nb);
        let mut blacks = vec![None; nb];
        for (k, (d, p)) in decoded.iter().zip(files).enumerate() {
            if d.raster.bands != 1 {
                return Err(DataError::BandCount {
                    path: p.clone(),
                    key: "band_files".into(),
                    frame: Some(frame_of(f)),
                    expected: 1,
                    found: d.raster.bands,
                });
            }
            if d.raster.sample_type() != ty {
                return Err(DataError::Decode {
                    path: p.clone(),
                    frame: Some(frame_of(f)),
                    reason: format!("sample type {:?} differs from the other bands' {:?}", d.raster.sample_type(), ty),
                });
            }
            let b = slot[k];
            blacks[b] = d.meta.black_level;
            for q in 0..px {
                out.copy_from(q * nb + b, &d.raster.samples, q);
            }
        }
        let r = Raster::new(self.width, self.height, nb, out).expect("sizes checked above");
        Ok((r, blacks))
    }

    /// Decodes an auxiliary image of frame `f` (mask, depth) and checks it has the dataset's size; errors name the
    /// file, the key it came from and the frame.
    fn read_sized(&self, p: &Path, f: &Frame, key: &str) -> Result<Raster, DataError> {
        let d = read_image_file(p, self.max_decode_bytes()).map_err(|reason| DataError::Decode {
            path: p.to_path_buf(),
            frame: Some(frame_of(f)),
            reason,
        })?;
        let r = d.raster;
        if (r.width, r.height) != (self.width, self.height) {
            return Err(DataError::ImageSize {
                path: p.to_path_buf(),
                key: key.into(),
                frame: Some(frame_of(f)),
                expected: (self.width, self.height),
                found: (r.width, r.height),
            });
        }
        Ok(r)
    }

    fn read_mask(&self, p: &Path, f: &Frame) -> Result<Vec<u8>, DataError> {
        let r = self.read_sized(p, f, "mask_path")?;
        let px = (self.width * self.height) as usize;
        Ok((0..px).map(|q| u8::from(r.samples.raw(q * r.bands) != 0.0)).collect())
    }

    /// Reads frame `i`'s depth file in metres (× `depth_unit_scale_factor`), row-major; `None` without one. A depth
    /// file with more than one band is an error naming it (an image given as a depth map).
    pub fn read_depth(&self, i: usize) -> Result<Option<Vec<f32>>, DataError> {
        let f = &self.frames[i];
        let Some(p) = &f.depth else { return Ok(None) };
        let r = self.read_sized(p, f, "depth_file_path")?;
        if r.bands != 1 {
            return Err(DataError::BandCount {
                path: p.to_path_buf(),
                key: "depth_file_path".into(),
                frame: Some(frame_of(f)),
                expected: 1,
                found: r.bands,
            });
        }
        let s = self.depth_unit_scale_factor;
        let px = (self.width * self.height) as usize;
        Ok(Some((0..px).map(|q| (r.samples.raw(q * r.bands) * s) as f32).collect()))
    }
}

/// A model value that is finite and within ±[`MAX_MODEL_VALUE`].
fn plausible(v: f64) -> bool {
    v.abs() <= MAX_MODEL_VALUE
}

/// The file's alpha channel, when it has one besides at least one colour channel.
fn colour_alpha(d: &DecodedImage) -> Option<AlphaChannel> {
    d.meta.alpha.filter(|a| d.raster.bands >= 2 && a.index < d.raster.bands)
}

fn select_channels(r: &Raster, order: &[usize]) -> Raster {
    let px = r.width as usize * r.height as usize;
    let nb = order.len();
    if order.len() == r.bands && order.iter().enumerate().all(|(i, &o)| i == o) {
        return r.clone();
    }
    let mut out = Samples::zeros(r.sample_type(), px * nb);
    for q in 0..px {
        for (b, &c) in order.iter().enumerate() {
            out.copy_from(q * nb + b, &r.samples, q * r.bands + c);
        }
    }
    Raster::new(r.width, r.height, nb, out).expect("shape follows from the source")
}
