//! The scene simulator behind `msnerf simulate`: synthetic multi-view multispectral datasets with exact
//! geometry and radiometry, written in the spec/dataset.md format.
//!
//! - [`scene`]: scene files (`configs/scenes/*.yaml`, built-ins `campus` and `ci-small`), [`SceneDesc::load`].
//! - [`bands`], [`spectra`]: bands (MS600Pro by default, any B) and reflectance spectra integrated per band.
//! - [`geometry`]: boxes, ellipsoid crowns, trunks, the ground with painted regions and water, the backdrop.
//! - [`cameras`]: orbit rings, lawnmower grids, explicit poses; MS600Pro pinhole intrinsics.
//! - [`effects`]: the light model and the opt-in effects (sun + sky with shadows, vegetation BRDF,
//!   misregistration, vignetting, exposure drift, noise with quantisation). Absent effects run no code.
//! - [`render`]: one ray per pixel, f64, deterministic for a seed at any thread count.
//! - [`sparse`]: simulated SfM points with their tracks (`--sparse-points`), for depth supervision.
//! - [`sensor`]: the camera in the simulator (`--raw-rig`): the flight as raw single-band files with the maker's tags.
//! - [`writer`]: TIFF/PLY/JSON files and the staging folder that makes writing atomic.
//!
//! Frames: the scene is described and rendered in a local frame (metres, x east, y north, z up, ground z = 0);
//! `world_offset` is added to every written coordinate (poses, point cloud), in f64.
//!
//! ```no_run
//! let scene = msnerf::sim::SceneDesc::load("ci-small").unwrap();
//! let report = msnerf::sim::simulate(&scene, &msnerf::sim::SimOptions::default(), "out/ci".as_ref()).unwrap();
//! println!("{report}");
//! ```

pub mod bands;
pub mod cameras;
pub mod effects;
pub mod error;
pub mod geometry;
pub mod output;
pub mod render;
pub mod scene;
pub mod sensor;
pub mod sparse;
pub mod spectra;
pub mod texture;
pub mod truth;
pub mod writer;

pub use error::SimError;
pub use output::{simulate, SimReport};
pub use render::{Prepared, ViewImage};
pub use scene::SceneDesc;

/// Stored sample type of the images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum PixelFormat {
    /// 32-bit float reflectance.
    #[default]
    F32,
    /// 16-bit integers with `pixel_scale` (12-bit DNs as-is when `noise` quantises, else value · 32767.5).
    U16,
}

/// `pixel_scale` of u16 images without quantisation: values in [0, 2] (sunlit walls can exceed 1).
pub const U16_SCALE: f64 = 32767.5;

/// Run-level choices; `None` keeps the scene's value.
#[derive(Debug, Clone)]
pub struct SimOptions {
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Total number of views (spread over the orbit groups, see `cameras`).
    pub views: Option<usize>,
    pub format: PixelFormat,
    pub seed: Option<u64>,
    /// One single-band TIFF per band (`band_files`) instead of one multi-band TIFF per view.
    pub band_files: bool,
    /// Worker threads; 0 = all available cores.
    pub threads: usize,
    /// Target number of ground-truth points.
    pub points: usize,
    /// Replace an existing output folder.
    pub overwrite: bool,
    /// Simulated SfM points (`sparse_points.json`, [`sparse`]); None: not written.
    pub sparse_points: Option<sparse::SparseOptions>,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            width: None,
            height: None,
            views: None,
            format: PixelFormat::F32,
            seed: None,
            band_files: false,
            threads: 0,
            points: 200_000,
            overwrite: false,
            sparse_points: None,
        }
    }
}

impl Prepared {
    /// Resolves a scene with options: bands, band-integrated materials, geometry, poses, active effects.
    pub fn new(desc: &SceneDesc, opts: &SimOptions) -> Result<Prepared, SimError> {
        let opt_err = |key: &str, reason: String| SimError::Option { key: key.into(), reason };
        let bands = bands::resolve_bands(desc);
        let integrators: Vec<spectra::BandIntegrator> =
            bands.iter().map(|b| spectra::BandIntegrator::new(&b.response)).collect();
        let names: Vec<&String> = desc.materials.keys().collect();
        let materials: Vec<render::Material> = desc
            .materials
            .iter()
            .map(|(name, m)| {
                let s = match (&m.spectrum, m.flat) {
                    (Some(k), _) => spectra::Spectrum::new(k.iter().map(|p| (p[0], p[1])).collect())
                        .expect("validated when the scene was loaded"),
                    (None, f) => spectra::Spectrum::flat(f.unwrap_or(0.0)),
                };
                render::Material {
                    name: name.clone(),
                    refl: integrators.iter().map(|i| i.integrate(&s)).collect(),
                    vegetation: m.vegetation,
                    texture: m.texture,
                }
            })
            .collect();
        let mat = |n: &str| names.iter().position(|m| *m == n).expect("material names validated");
        let world = geometry::World::new(desc, &mat);
        let (w, h) = match (opts.width, opts.height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => {
                (w, ((w as f64 * desc.image.height as f64 / desc.image.width as f64).round() as u32).max(1))
            }
            (None, Some(h)) => {
                (((h as f64 * desc.image.width as f64 / desc.image.height as f64).round() as u32).max(1), h)
            }
            (None, None) => (desc.image.width, desc.image.height),
        };
        if w == 0 || h == 0 || w > 16384 || h > 16384 {
            return Err(opt_err("width", format!("image size {w}x{h} must be 1..=16384 pixels")));
        }
        let camera = cameras::intrinsics(w, h, desc.image.hfov_deg);
        let poses = cameras::scene_poses(desc, opts.views).map_err(|r| opt_err("views", r))?;
        for (i, p) in poses.iter().enumerate() {
            if !world.contains([p[0][3], p[1][3], p[2][3]]) {
                return Err(SimError::Scene {
                    file: desc.source.clone(),
                    key: "cameras".into(),
                    reason: format!("view {i} lies outside the dome of radius ground.extent or below the ground"),
                });
            }
            let dev = (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .map(|(i, j)| ((0..3).map(|k| p[k][i] * p[k][j]).sum::<f64>() - f64::from(u8::from(i == j))).abs())
                .fold(0.0, f64::max);
            if dev > 1e-9 {
                return Err(SimError::Scene {
                    file: desc.source.clone(),
                    key: "cameras".into(),
                    reason: format!("view {i}: rotation is not orthonormal (deviation {dev:.2e})"),
                });
            }
        }
        let effects = desc.effects.active();
        let mut transforms = vec![render::BandView::REFERENCE];
        let view_index =
            |transforms: &mut Vec<render::BandView>, v: render::BandView| match transforms.iter().position(|x| *x == v)
            {
                Some(i) => i,
                None => {
                    transforms.push(v);
                    transforms.len() - 1
                }
            };
        let mut band_transform = vec![0; bands.len()];
        if let Some(m) = &effects.misregistration {
            let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
            for s in &m.bands {
                let b = bands.iter().position(|x| x.name.eq_ignore_ascii_case(&s.band)).expect("validated");
                // Sampling point q = R(−θ)(p − t − c) + c.
                let (sn, cs) = (-s.rotation_deg.to_radians()).sin_cos();
                let a = [[cs, -sn], [sn, cs]];
                let (px, py) = (-s.shift_px[0] - cx, -s.shift_px[1] - cy);
                let t = [a[0][0] * px + a[0][1] * py + cx, a[1][0] * px + a[1][1] * py + cy];
                let tr = if s.rotation_deg == 0.0 {
                    render::Affine2 { a: [[1.0, 0.0], [0.0, 1.0]], t: [-s.shift_px[0], -s.shift_px[1]] }
                } else {
                    render::Affine2 { a, t }
                };
                band_transform[b] = view_index(&mut transforms, render::BandView { affine: tr, offset: [0.0; 3] });
            }
        }
        if let Some(r) = &effects.rig_parallax {
            for o in &r.bands {
                let b = bands.iter().position(|x| x.name.eq_ignore_ascii_case(&o.band)).expect("validated");
                let v = render::BandView { affine: render::Affine2::IDENTITY, offset: o.offset_m };
                band_transform[b] = view_index(&mut transforms, v);
            }
        }
        let total = poses.len() * (w as usize) * (h as usize);
        let point_stride = total.div_ceil(opts.points.max(1)).max(1);
        Ok(Prepared {
            name: desc.name.clone(),
            bands,
            materials,
            world,
            camera,
            poses,
            effects,
            seed: opts.seed.unwrap_or(desc.seed),
            world_offset: desc.world_offset,
            crs: desc.crs.as_deref().map(crate::geo::Crs::parse).transpose().map_err(|e| SimError::Scene {
                file: desc.source.clone(),
                key: "crs".into(),
                reason: e.to_string(),
            })?,
            transforms,
            band_transform,
            point_stride,
            trees: desc.trees.clone(),
        })
    }
}
