//! Scene descriptions: the serde types of `configs/scenes/*.yaml`, loading (built-in name or file) and the
//! checks that need more than serde (material names, counts, ranges). Every type denies unknown fields, so a
//! typo is an error naming the file and the key.
//!
//! Units: metres and degrees; the scene's local frame is x east, y north, z up, with the ground at z = 0.
//! `world_offset` (e.g. UTM easting/northing/altitude) is added to every written coordinate.

// Range checks are written `!(x > 0.0)` on purpose: they must also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use super::effects::EffectsDesc;
use super::error::SimError;

/// A whole scene file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDesc {
    /// Where the scene came from (file path or `built-in scene `name``); set by the loader, named in errors.
    #[serde(skip)]
    pub source: String,
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Added to every written coordinate (poses, point cloud); metres.
    #[serde(default)]
    pub world_offset: [f64; 3],
    /// The projected CRS `world_offset` is in (`EPSG:32650`, or OGC WKT): written as the dataset's `crs`, so its
    /// outputs (LAS, PLY, GeoTIFF) carry it.
    #[serde(default)]
    pub crs: Option<String>,
    /// Seed for every random choice (noise, drift); `--seed` overrides.
    #[serde(default)]
    pub seed: u64,
    /// Explicit bands; absent (and no `band_range`) means the MS600Pro's six.
    #[serde(default)]
    pub bands: Option<Vec<BandDesc>>,
    /// Evenly spaced Gaussian bands (hyperspectral scenes).
    #[serde(default)]
    pub band_range: Option<BandRangeDesc>,
    #[serde(default)]
    pub image: ImageDesc,
    pub materials: BTreeMap<String, MaterialDesc>,
    pub ground: GroundDesc,
    /// Flat regions painted on the ground, later entries on top.
    #[serde(default)]
    pub regions: Vec<RegionDesc>,
    /// Water regions (flat, at ground level), drawn on top of `regions`.
    #[serde(default)]
    pub water: Vec<RegionDesc>,
    #[serde(default)]
    pub boxes: Vec<BoxDesc>,
    #[serde(default)]
    pub trees: Vec<TreeDesc>,
    pub cameras: Vec<CameraGroupDesc>,
    #[serde(default)]
    pub effects: EffectsDesc,
}

/// One band: a Gaussian (`fwhm_nm`) or a tabulated `response`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandDesc {
    pub name: String,
    pub center_nm: f64,
    #[serde(default)]
    pub fwhm_nm: Option<f64>,
    /// (nm, relative weight) pairs instead of a Gaussian.
    #[serde(default)]
    pub response: Option<Vec<[f64; 2]>>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandRangeDesc {
    pub start_nm: f64,
    pub end_nm: f64,
    pub count: usize,
    pub fwhm_nm: f64,
}

/// Most views a scene or `--views` may ask for (each is an image of every band written to disk).
pub const MAX_VIEWS: usize = 100_000;

/// Intrinsics and output size; the defaults are the MS600Pro (HFOV 49.6°, 4:3 pinhole) at 256x192.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageDesc {
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
    #[serde(default = "default_hfov")]
    pub hfov_deg: f64,
}

fn default_width() -> u32 {
    256
}
fn default_height() -> u32 {
    192
}
fn default_hfov() -> f64 {
    MS600PRO_HFOV_DEG
}

impl Default for ImageDesc {
    fn default() -> Self {
        ImageDesc { width: default_width(), height: default_height(), hfov_deg: default_hfov() }
    }
}

/// MS600Pro horizontal field of view (paper Table 2).
pub const MS600PRO_HFOV_DEG: f64 = 49.6;

/// A material: a reflectance spectrum (`spectrum` knots or `flat`), optionally vegetation (BRDF effect).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDesc {
    /// (nm, reflectance) pairs, linear between them, constant beyond the ends.
    #[serde(default)]
    pub spectrum: Option<Vec<[f64; 2]>>,
    /// A constant reflectance in every band.
    #[serde(default)]
    pub flat: Option<f64>,
    /// Gets the `vegetation_brdf` effect.
    #[serde(default)]
    pub vegetation: bool,
    /// Albedo texture (opt-in; `super::texture`): `{scale: METRES, contrast: 0..1, octaves: N}`.
    #[serde(default)]
    pub texture: Option<super::texture::TextureDesc>,
}

/// The ground plane z = 0: a disc of radius `extent` around `center`, closed by a hemispherical backdrop
/// ("horizon") of the same radius, so every ray hits something at a finite distance.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundDesc {
    pub material: String,
    #[serde(default)]
    pub center: [f64; 2],
    #[serde(default = "default_extent")]
    pub extent: f64,
    /// Material of the backdrop dome; default: the ground's.
    #[serde(default)]
    pub horizon: Option<String>,
}

fn default_extent() -> f64 {
    2000.0
}

/// A flat region: exactly one of `rect`, `polygon`, `circle`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionDesc {
    pub material: String,
    #[serde(default)]
    pub rect: Option<RectDesc>,
    /// [x, y] vertices (either orientation).
    #[serde(default)]
    pub polygon: Option<Vec<[f64; 2]>>,
    #[serde(default)]
    pub circle: Option<CircleDesc>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RectDesc {
    pub center: [f64; 2],
    pub size: [f64; 2],
    #[serde(default)]
    pub yaw_deg: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CircleDesc {
    pub center: [f64; 2],
    pub radius: f64,
}

/// A building: a box standing on the ground, rotated by `yaw_deg` about its vertical axis.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxDesc {
    pub center: [f64; 2],
    /// [x size, y size, height] before the yaw.
    pub size: [f64; 3],
    #[serde(default)]
    pub yaw_deg: f64,
    /// Walls.
    pub material: String,
    /// Top face; default: `material`.
    #[serde(default)]
    pub roof: Option<String>,
}

/// A tree: a vertical cylindrical trunk from the ground to `trunk_height`, and an ellipsoidal crown with
/// semi-axes `crown` = [rx, ry, rz] centred at height `trunk_height + rz` (the crown sits on the trunk).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TreeDesc {
    pub position: [f64; 2],
    pub trunk_height: f64,
    #[serde(default = "default_trunk_radius")]
    pub trunk_radius: f64,
    pub crown: [f64; 3],
    pub crown_material: String,
    pub trunk_material: String,
}

fn default_trunk_radius() -> f64 {
    0.2
}

/// One group of cameras: exactly one of `orbit`, `grid`, `poses`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraGroupDesc {
    #[serde(default)]
    pub orbit: Option<OrbitDesc>,
    #[serde(default)]
    pub grid: Option<GridDesc>,
    #[serde(default)]
    pub poses: Option<Vec<PoseDesc>>,
}

/// A circling flight: `count` views evenly spaced on a circle, each facing the centre with the gimbal tilted
/// by `tilt_deg` (negative = below the horizon; the paper flies at -60°).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OrbitDesc {
    pub center: [f64; 2],
    pub radius: f64,
    /// Above the ground (z = 0).
    pub height: f64,
    #[serde(default = "default_tilt")]
    pub tilt_deg: f64,
    pub count: usize,
    /// Azimuth of the first view, counter-clockwise from east.
    #[serde(default)]
    pub start_deg: f64,
}

fn default_tilt() -> f64 {
    -60.0
}

/// A lawnmower grid: `rows` x `cols` views over a rectangle, serpentine order, gimbal `tilt_deg` (-90 = nadir),
/// image top towards `heading_deg` (clockwise from north).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridDesc {
    pub center: [f64; 2],
    pub size: [f64; 2],
    pub height: f64,
    pub rows: usize,
    pub cols: usize,
    #[serde(default = "default_nadir")]
    pub tilt_deg: f64,
    #[serde(default)]
    pub heading_deg: f64,
}

fn default_nadir() -> f64 {
    -90.0
}

/// An explicit pose: `position` plus `look_at` (and optional `up`, default +z), or a 4x4 camera-to-world
/// `transform_matrix` (OpenGL axes) in the scene's local frame.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseDesc {
    #[serde(default)]
    pub position: Option<[f64; 3]>,
    #[serde(default)]
    pub look_at: Option<[f64; 3]>,
    #[serde(default)]
    pub up: Option<[f64; 3]>,
    #[serde(default)]
    pub transform_matrix: Option<[[f64; 4]; 4]>,
}

/// Names of the built-in scenes (`configs/scenes/<name>.yaml`, compiled in).
pub const BUILTIN_SCENES: [(&str, &str); 6] = [
    ("campus", include_str!("../../configs/scenes/campus.yaml")),
    ("ci-small", include_str!("../../configs/scenes/ci-small.yaml")),
    ("rig-low", include_str!("../../configs/scenes/rig-low.yaml")),
    ("ci-textured", include_str!("../../configs/scenes/ci-textured.yaml")),
    ("flight-rural", include_str!("../../configs/scenes/flight-rural.yaml")),
    ("flight-urban", include_str!("../../configs/scenes/flight-urban.yaml")),
];

impl SceneDesc {
    /// A built-in scene by name, or a YAML file by path.
    pub fn load(name_or_path: &str) -> Result<SceneDesc, SimError> {
        if let Some((n, text)) = BUILTIN_SCENES.iter().find(|(n, _)| *n == name_or_path) {
            return SceneDesc::from_yaml(text, &format!("built-in scene `{n}`"));
        }
        let p = Path::new(name_or_path);
        let text = std::fs::read_to_string(p).map_err(|e| SimError::Scene {
            file: name_or_path.to_string(),
            key: String::new(),
            reason: if p.exists() {
                e.to_string()
            } else {
                format!(
                    "no such file, and not a built-in scene ({})",
                    BUILTIN_SCENES.iter().map(|s| s.0).collect::<Vec<_>>().join(", ")
                )
            },
        })?;
        SceneDesc::from_yaml(&text, name_or_path)
    }

    /// Parses and checks YAML text; `file` names the source in errors.
    pub fn from_yaml(text: &str, file: &str) -> Result<SceneDesc, SimError> {
        if let Some(key) = crate::util::yaml::first_non_finite(text) {
            return Err(SimError::Scene { file: file.to_string(), key, reason: "not a finite number".into() });
        }
        // serde_yaml's message already names the key path (e.g. `cameras[0].orbit: unknown field ...`).
        let desc: SceneDesc = serde_yaml::from_str(text).map_err(|e| SimError::Scene {
            file: file.to_string(),
            key: String::new(),
            reason: e.to_string(),
        })?;
        let mut desc = desc;
        desc.source = file.to_string();
        desc.validate().map_err(|(key, reason)| SimError::Scene { file: file.to_string(), key, reason })?;
        Ok(desc)
    }

    /// Checks what serde cannot: known material names, one shape per region, positive sizes and counts.
    fn validate(&self) -> Result<(), (String, String)> {
        let bad = |k: String, r: &str| Err((k, r.to_string()));
        let has = |m: &str| self.materials.contains_key(m);
        let unknown = |k: String, m: &str| -> Result<(), (String, String)> {
            Err((
                k,
                format!(
                    "unknown material `{m}` (materials: {})",
                    self.materials.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            ))
        };
        if let Some(c) = &self.crs {
            match crate::geo::Crs::parse(c) {
                Ok(crs) if crs.kind == crate::geo::CrsKind::Projected => {}
                Ok(crs) => return bad("crs".into(), &format!("{} is not a projected CRS in metres", crs.describe())),
                Err(e) => return bad("crs".into(), &e.to_string()),
            }
        }
        if self.bands.is_some() && self.band_range.is_some() {
            return bad("band_range".into(), "give either `bands` or `band_range`, not both");
        }
        if let Some(bands) = &self.bands {
            if bands.is_empty() {
                return bad("bands".into(), "empty band list");
            }
            for (i, b) in bands.iter().enumerate() {
                if bands[..i].iter().any(|o| o.name.eq_ignore_ascii_case(&b.name)) {
                    return bad(format!("bands[{i}].name"), "duplicate band name");
                }
                if !(100.0..=20_000.0).contains(&b.center_nm) {
                    return bad(format!("bands[{i}].center_nm"), "must be a wavelength in 100..=20000 nm");
                }
                if b.fwhm_nm.is_some_and(|w| w > 1000.0) {
                    return bad(format!("bands[{i}].fwhm_nm"), "must be at most 1000 nm");
                }
                match (&b.fwhm_nm, &b.response) {
                    (Some(_), Some(_)) => {
                        return bad(format!("bands[{i}].response"), "give either `fwhm_nm` or `response`")
                    }
                    (None, None) => return bad(format!("bands[{i}].fwhm_nm"), "missing: give `fwhm_nm` or `response`"),
                    (Some(w), None) if !(*w > 0.0 && w.is_finite()) => {
                        return bad(format!("bands[{i}].fwhm_nm"), "must be positive")
                    }
                    (None, Some(r)) => {
                        if r.len() < 2 || r.windows(2).any(|w| w[1][0] <= w[0][0]) || r.iter().any(|k| k[1] < 0.0) {
                            return bad(
                                format!("bands[{i}].response"),
                                "needs two or more [nm, weight] pairs, increasing nm, weights >= 0",
                            );
                        }
                        if r.iter().all(|k| k[1] == 0.0) {
                            return bad(format!("bands[{i}].response"), "all weights are zero");
                        }
                    }
                    _ => {}
                }
            }
        }
        if let Some(r) = &self.band_range {
            if r.count == 0 || r.count > 4096 || !(r.end_nm >= r.start_nm) || !(r.fwhm_nm > 0.0) {
                return bad("band_range".into(), "needs 1..=4096 bands, end_nm >= start_nm and fwhm_nm > 0");
            }
            if r.count > 1 && r.end_nm == r.start_nm {
                return bad("band_range.end_nm".into(), "must exceed start_nm for more than one band");
            }
        }
        let im = &self.image;
        if im.width == 0 || im.height == 0 || im.width > 16384 || im.height > 16384 {
            return bad("image.width".into(), "image size must be 1..=16384 pixels");
        }
        if !(im.hfov_deg > 0.0 && im.hfov_deg < 179.0) {
            return bad("image.hfov_deg".into(), "must be in (0, 179)");
        }
        if self.materials.is_empty() {
            return bad("materials".into(), "no materials");
        }
        for (name, m) in &self.materials {
            let k = format!("materials.{name}");
            match (&m.spectrum, m.flat) {
                (Some(_), Some(_)) => return bad(k, "give either `spectrum` or `flat`, not both"),
                (None, None) => return bad(k, "missing `spectrum` or `flat`"),
                (Some(s), None) => {
                    let knots = s.iter().map(|p| (p[0], p[1])).collect();
                    if let Err(e) = super::spectra::Spectrum::new(knots) {
                        return Err((format!("{k}.spectrum"), e));
                    }
                }
                (None, Some(f)) if !f.is_finite() => return bad(format!("{k}.flat"), "must be finite"),
                _ => {}
            }
            if let Some(t) = &m.texture {
                t.validate().map_err(|(key, e)| (format!("{k}.{key}"), e))?;
            }
        }
        if !has(&self.ground.material) {
            return unknown("ground.material".into(), &self.ground.material);
        }
        if let Some(h) = &self.ground.horizon {
            if !has(h) {
                return unknown("ground.horizon".into(), h);
            }
        }
        if !(self.ground.extent > 0.0 && self.ground.extent.is_finite()) {
            return bad("ground.extent".into(), "must be positive");
        }
        for (list, regions) in [("regions", &self.regions), ("water", &self.water)] {
            for (i, r) in regions.iter().enumerate() {
                let k = format!("{list}[{i}]");
                if !has(&r.material) {
                    return unknown(format!("{k}.material"), &r.material);
                }
                let n = r.rect.is_some() as u8 + r.polygon.is_some() as u8 + r.circle.is_some() as u8;
                if n != 1 {
                    return bad(k, "give exactly one of `rect`, `polygon`, `circle`");
                }
                if r.polygon.as_ref().is_some_and(|p| p.len() < 3) {
                    return bad(format!("{k}.polygon"), "needs at least three vertices");
                }
                if r.rect.as_ref().is_some_and(|p| !(p.size[0] > 0.0 && p.size[1] > 0.0)) {
                    return bad(format!("{k}.rect.size"), "must be positive");
                }
                if r.circle.as_ref().is_some_and(|c| !(c.radius > 0.0)) {
                    return bad(format!("{k}.circle.radius"), "must be positive");
                }
            }
        }
        for (i, b) in self.boxes.iter().enumerate() {
            let k = format!("boxes[{i}]");
            if !b.size.iter().all(|&s| s > 0.0 && s.is_finite()) {
                return bad(format!("{k}.size"), "must be positive");
            }
            if !has(&b.material) {
                return unknown(format!("{k}.material"), &b.material);
            }
            if let Some(r) = &b.roof {
                if !has(r) {
                    return unknown(format!("{k}.roof"), r);
                }
            }
        }
        for (i, t) in self.trees.iter().enumerate() {
            let k = format!("trees[{i}]");
            if !(t.trunk_height >= 0.0 && t.trunk_radius > 0.0) {
                return bad(format!("{k}.trunk_height"), "trunk_height must be >= 0 and trunk_radius > 0");
            }
            if !t.crown.iter().all(|&s| s > 0.0 && s.is_finite()) {
                return bad(format!("{k}.crown"), "semi-axes must be positive");
            }
            for (key, m) in [("crown_material", &t.crown_material), ("trunk_material", &t.trunk_material)] {
                if !has(m) {
                    return unknown(format!("{k}.{key}"), m);
                }
            }
        }
        if self.cameras.is_empty() {
            return bad("cameras".into(), "no camera groups");
        }
        for (i, c) in self.cameras.iter().enumerate() {
            let k = format!("cameras[{i}]");
            let n = c.orbit.is_some() as u8 + c.grid.is_some() as u8 + c.poses.is_some() as u8;
            if n != 1 {
                return bad(k, "give exactly one of `orbit`, `grid`, `poses`");
            }
            if let Some(o) = &c.orbit {
                if o.count == 0 || o.count > MAX_VIEWS || !(o.radius >= 0.0) || !(o.height > 0.0) {
                    return bad(format!("{k}.orbit"), "needs 0 < count <= 100000, radius >= 0, height > 0");
                }
                if !(o.tilt_deg > -90.0 - 1e-9 && o.tilt_deg < 90.0) {
                    return bad(format!("{k}.orbit.tilt_deg"), "must be in [-90, 90)");
                }
            }
            if let Some(g) = &c.grid {
                if g.rows == 0 || g.cols == 0 || !(g.height > 0.0) || !(g.size[0] >= 0.0 && g.size[1] >= 0.0) {
                    return bad(format!("{k}.grid"), "needs rows, cols > 0, height > 0, size >= 0");
                }
                if !(g.tilt_deg >= -90.0 && g.tilt_deg < 90.0) {
                    return bad(format!("{k}.grid.tilt_deg"), "must be in [-90, 90)");
                }
            }
            if let Some(p) = &c.poses {
                if p.is_empty() {
                    return bad(format!("{k}.poses"), "empty list");
                }
                for (j, q) in p.iter().enumerate() {
                    let ok = matches!(
                        (&q.position, &q.look_at, &q.transform_matrix),
                        (Some(_), Some(_), None) | (None, None, Some(_))
                    );
                    if !ok || (q.up.is_some() && q.transform_matrix.is_some()) {
                        return bad(
                            format!("{k}.poses[{j}]"),
                            "give `position` + `look_at` (+ optional `up`), or `transform_matrix`",
                        );
                    }
                }
            }
        }
        self.effects.validate(self).map_err(|(k, r)| (format!("effects.{k}"), r))
    }
}
