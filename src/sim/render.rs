//! The renderer: a scene prepared for rendering ([`Prepared`]) and one view rendered to band values, ray
//! depth and ground-truth surface samples ([`Prepared::render_view`]).
//!
//! One ray per pixel through the pixel centre, built by `data::camera::generate_ray` (the trainer's own ray
//! function, so both agree bit for bit); no anti-aliasing, so a pixel's value and depth belong to one surface
//! point. Bands that `misregistration` or `rig_parallax` moves cast their own ray (one per distinct band view);
//! all others share the reference ray. Every random draw is a hash of (seed, view, band, pixel), so output does not depend
//! on thread count or order.

use crate::data::camera::{generate_ray, Camera, Intrinsics};

use super::bands::SimBand;
use super::cameras::Mat4;
use super::effects::{self, EffectsDesc};
use super::geometry::{Hit, HitKind, World, SHADOW_EPS, V3};

/// The light of a scene as [`Prepared::shade`] takes it: the sun (unit direction, sky fraction) and the
/// vegetation BRDF, each `None` when its effect is off.
pub type LightModel<'a> = (Option<(V3, f64)>, Option<&'a effects::BrdfDesc>);

/// A material with its band values.
#[derive(Debug, Clone)]
pub struct Material {
    pub name: String,
    /// Band-integrated reflectance, one per band.
    pub refl: Vec<f64>,
    pub vegetation: bool,
    /// Albedo texture factor of the hit point (all bands alike), when the scene asks for one.
    pub texture: Option<super::texture::TextureDesc>,
}

/// An image-point transform p ↦ A·p + t (pixels), mapping a band's output point to its sampling point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine2 {
    pub a: [[f64; 2]; 2],
    pub t: [f64; 2],
}

impl Affine2 {
    pub const IDENTITY: Affine2 = Affine2 { a: [[1.0, 0.0], [0.0, 1.0]], t: [0.0, 0.0] };
    fn apply(&self, u: f64, v: f64) -> (f64, f64) {
        (self.a[0][0] * u + self.a[0][1] * v + self.t[0], self.a[1][0] * u + self.a[1][1] * v + self.t[1])
    }
}

/// How one band's image is sampled: its image-point transform (misregistration) and its camera centre offset in
/// the frame camera's axes (rig parallax, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandView {
    pub affine: Affine2,
    pub offset: [f64; 3],
}

impl BandView {
    pub const REFERENCE: BandView = BandView { affine: Affine2::IDENTITY, offset: [0.0; 3] };
}

/// Everything rendering needs, resolved from a scene and the options.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub name: String,
    pub bands: Vec<SimBand>,
    pub materials: Vec<Material>,
    pub world: World,
    pub camera: Camera,
    /// Camera-to-world, local frame.
    pub poses: Vec<Mat4>,
    /// Active effects only.
    pub effects: EffectsDesc,
    pub seed: u64,
    pub world_offset: [f64; 3],
    /// The scene's `crs` (validated), as written into `transforms.json`.
    pub crs: Option<crate::geo::Crs>,
    /// Distinct band views; index 0 is the reference (the frame camera's ray, depth and points).
    pub transforms: Vec<BandView>,
    /// Per band: index into `transforms`.
    pub band_transform: Vec<usize>,
    /// Ground-truth point stride over (view, pixel).
    pub point_stride: usize,
    /// The scene's trees (their truth: positions, heights, crowns).
    pub trees: Vec<super::scene::TreeDesc>,
}

/// One rendered view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewImage {
    /// Row-major, bands interleaved (chunky), values after all effects.
    pub values: Vec<f32>,
    /// Quantised DNs, same layout, when `noise.bits > 0`.
    pub dn: Option<Vec<u16>>,
    /// Distance along the unit reference ray (metres).
    pub depth: Vec<f32>,
    /// With `rig_parallax`: every band as the frame camera sees it (the reference ray's surface; gains and
    /// vignetting applied, no noise), the registered truth the bands should agree with. Same layout as `values`.
    pub registered: Option<Vec<f32>>,
    /// Ground-truth samples: local hit point and material index.
    pub points: Vec<(V3, usize)>,
}

impl Prepared {
    /// Per-view, per-band gain (1 without `exposure_drift`).
    pub fn gain(&self, view: usize, band: usize) -> f64 {
        match &self.effects.exposure_drift {
            Some(d) => effects::drift_gain(d, self.seed, view, band),
            None => 1.0,
        }
    }

    /// Renders view `vi`.
    pub fn render_view(&self, vi: usize) -> ViewImage {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let nb = self.bands.len();
        let px = w * h;
        let k: Intrinsics<f64> = self.camera.intrinsics();
        let c2w = self.poses[vi];
        let rows = [c2w[0], c2w[1], c2w[2]];
        let (sun, brdf) = self.light_model();
        let gains: Option<Vec<f64>> =
            self.effects.exposure_drift.as_ref().map(|_| (0..nb).map(|b| self.gain(vi, b)).collect());
        let noise = self.effects.noise.as_ref();
        let quantised = noise.is_some_and(|n| n.bits > 0);
        let vig = self.effects.vignetting.as_ref();

        let mut values = vec![0f32; px * nb];
        let mut dn = if quantised { Some(vec![0u16; px * nb]) } else { None };
        let mut depth = vec![0f32; px];
        let mut points = Vec::new();
        let mut band_val = vec![0f64; nb];
        let mut registered = self.effects.rig_parallax.as_ref().map(|_| vec![0f32; px * nb]);
        let mut ref_val = vec![0f64; nb];
        let pt_phase = vi % self.point_stride;

        for row in 0..h {
            for col in 0..w {
                let p = row * w + col;
                let (u0, v0) = (col as f64 + 0.5, row as f64 + 0.5);
                for (ti, tr) in self.transforms.iter().enumerate() {
                    let (u, v) = if ti == 0 { (u0, v0) } else { tr.affine.apply(u0, v0) };
                    let mut ray = generate_ray(&k, &rows, v, u);
                    for (i, row) in rows.iter().enumerate() {
                        ray.origin[i] += (0..3).map(|j| row[j] * tr.offset[j]).sum::<f64>();
                    }
                    let (hit, light) = self.shade(ray.origin, ray.direction, sun, brdf);
                    if ti == 0 {
                        depth[p] = hit.t as f32;
                        if hit.kind != HitKind::Horizon && (p + pt_phase) % self.point_stride == 0 {
                            let q = [0, 1, 2].map(|i| ray.origin[i] + hit.t * ray.direction[i]);
                            points.push((q, hit.material));
                        }
                    }
                    let m = &self.materials[hit.material];
                    for ((bv, &bt), r) in band_val.iter_mut().zip(&self.band_transform).zip(&m.refl) {
                        if bt == ti {
                            *bv = r * light;
                        }
                    }
                    if ti == 0 {
                        for (rv, r) in ref_val.iter_mut().zip(&m.refl) {
                            *rv = r * light;
                        }
                    }
                }
                let vf = vig.map(|d| effects::vignette(d, self.camera.width, self.camera.height, u0, v0));
                for b in 0..nb {
                    let mut x = band_val[b];
                    let mut y = ref_val[b];
                    if let Some(g) = &gains {
                        x *= g[b];
                        y *= g[b];
                    }
                    if let Some(f) = vf {
                        x *= f;
                        y *= f;
                    }
                    if let Some(reg) = registered.as_mut() {
                        reg[p * nb + b] = y as f32;
                    }
                    if let Some(n) = noise {
                        let (y, q) = effects::apply_noise(n, x, self.seed, vi, b, p);
                        x = y;
                        if let (Some(d), Some(q)) = (dn.as_mut(), q) {
                            d[p * nb + b] = q;
                        }
                    }
                    values[p * nb + b] = x as f32;
                }
            }
        }
        ViewImage { values, dn, depth, points, registered }
    }

    /// The sun (direction, sky fraction) and the vegetation BRDF of the active effects, for [`Prepared::shade`].
    pub fn light_model(&self) -> LightModel<'_> {
        (
            self.effects.sun.as_ref().map(|s| (effects::sun_direction(s), s.sky_fraction)),
            self.effects.vegetation_brdf.as_ref(),
        )
    }

    /// Traces one ray (local frame, unit direction) and returns what it hit with the band-independent factor of
    /// its value: the light L (see `effects`) times the material's albedo texture at the hit. A band's value is
    /// the material's band reflectance times this factor.
    pub fn shade(&self, o: V3, d: V3, sun: Option<(V3, f64)>, brdf: Option<&effects::BrdfDesc>) -> (Hit, f64) {
        let hit = self.world.trace(o, d);
        let mut light = self.light(&hit, o, d, sun, brdf);
        if let Some(tex) = &self.materials[hit.material].texture {
            let q = [0, 1, 2].map(|i| o[i] + hit.t * d[i]);
            light *= tex.factor(self.seed, hit.material, q);
        }
        (hit, light)
    }

    /// The band-independent light factor L at a hit (see `effects`).
    fn light(&self, hit: &Hit, o: V3, d: V3, sun: Option<(V3, f64)>, brdf: Option<&effects::BrdfDesc>) -> f64 {
        let veg = brdf.filter(|_| self.materials[hit.material].vegetation);
        let view = [-d[0], -d[1], -d[2]];
        match sun {
            None => match veg {
                Some(b) => effects::rpv_factor(b, hit.normal, [0.0, 0.0, 1.0], view),
                None => 1.0,
            },
            Some((s, f)) => {
                let n = hit.normal;
                let lit = n[0] * s[0] + n[1] * s[1] + n[2] * s[2] > 0.0;
                let visible = lit && hit.kind != HitKind::Horizon && {
                    let p = [0, 1, 2].map(|i| o[i] + hit.t * d[i] + SHADOW_EPS * n[i]);
                    !self.world.occluded(p, s)
                };
                let b = match veg {
                    Some(b) if visible => effects::rpv_factor(b, n, s, view),
                    _ => 1.0,
                };
                effects::sun_sky_light(n, s, f, b, visible || (lit && hit.kind == HitKind::Horizon))
            }
        }
    }
}
