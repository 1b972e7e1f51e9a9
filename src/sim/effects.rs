//! Opt-in effects (`effects:` in a scene) and the light model. An effect that is absent, or present with
//! `enabled: false`, is dropped before rendering ([`EffectsDesc::active`]) and runs no code.
//!
//! Pixel value of band b at pixel p of view v (each factor is 1 when its effect is off):
//!
//! ```text
//! value = Q( ρ_b(hit) · L(hit) · g_{v,b} · V(p) + noise )
//! L     = (1 − f) · B · max(0, n·s) / sin(ε) · vis + f · (1 + n_z) / 2      (sun)
//! L     = B                                                                 (no sun: flat light)
//! ```
//!
//! - `sun`: s = unit vector to the sun (azimuth clockwise from north, elevation ε); f = `sky_fraction`, the
//!   diffuse share of the horizontal irradiance; vis ∈ {0, 1} from one shadow ray; the sky is isotropic and
//!   unoccluded, seen by a surface with view factor (1 + n_z)/2. A sunlit horizontal surface reads exactly ρ
//!   (reflectance calibration against horizontal irradiance); a shadowed one reads f·ρ.
//! - `vegetation_brdf`: B = RPV(θi, θv, g) / RPV(0, 0, 0) on `vegetation: true` materials only (else B = 1):
//!   Rahman-Pinty-Verstraete with M = (cosθi cosθv)^(k−1) / (cosθi + cosθv)^(1−k),
//!   F = (1 − Θ²) / (1 + 2Θ cos g + Θ²)^1.5 with cos g = l·v (g = 0 is backscatter: Θ < 0 favours it),
//!   H = 1 + (1 − ρc) / (1 + G), G = |tanθi·t_l − tanθv·t_v| (the hot spot at G = 0). l is the sun direction,
//!   or the zenith without `sun`; v points to the camera. Normalised so nadir view under zenith light gives 1.
//! - `misregistration`: band b's pixel p shows the scene at image point R(−θ)(p − t − c) + c (c the image
//!   centre): the band's image is the reference image rotated by θ (clockwise as displayed, image y down)
//!   about c, then shifted by t = `shift_px` (+x right, +y down). Rendered by casting that band's own ray,
//!   so an integer shift is an exact pixel shift (no resampling).
//! - `rig_parallax`: band b is seen by its own camera, the frame camera moved by `offset_m` (its axes, metres):
//!   every pixel casts that camera's ray, so the band's image differs from the reference's by a parallax that
//!   depends on depth (no 2D warp undoes it at every depth). With `write_rig_cameras` the dataset says so
//!   (`rig_cameras`, docs/dataset.md); depth maps and truth points stay the frame camera's.
//! - `vignetting`: V = 1 + k1 r² + k2 r⁴ + k3 r⁶, r = |p − c| / half-diagonal.
//! - `exposure_drift`: g_{v,b} = gains[v] (cycled), else 1 + std·N(v), times 1 + band_std·N(v, b).
//! - `noise`: Gaussian with variance std² + shot·value, then (bits > 0) clamped to [0, full_scale] and
//!   quantised to round(value / full_scale · (2^bits − 1)) DN.

// Range checks are written `!(x > 0.0)` on purpose: they must also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use glam::DVec3;
use serde::Deserialize;

use super::bands::resolve_bands;
use super::scene::SceneDesc;

#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct EffectsDesc {
    #[serde(default)]
    pub sun: Option<SunDesc>,
    #[serde(default)]
    pub vegetation_brdf: Option<BrdfDesc>,
    #[serde(default)]
    pub misregistration: Option<MisregistrationDesc>,
    #[serde(default)]
    pub rig_parallax: Option<RigParallaxDesc>,
    #[serde(default)]
    pub vignetting: Option<VignettingDesc>,
    #[serde(default)]
    pub exposure_drift: Option<DriftDesc>,
    #[serde(default)]
    pub noise: Option<NoiseDesc>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SunDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Clockwise from north (y), degrees.
    pub azimuth_deg: f64,
    /// Above the horizon, degrees, in (0, 90].
    pub elevation_deg: f64,
    /// Diffuse (sky) share of the horizontal irradiance, [0, 1].
    #[serde(default = "default_sky")]
    pub sky_fraction: f64,
}

fn default_sky() -> f64 {
    0.15
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BrdfDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Minnaert-like exponent (k < 1: bowl shape, brighter at grazing angles).
    #[serde(default = "default_k")]
    pub k: f64,
    /// Henyey-Greenstein asymmetry Θ (negative: backscatter).
    #[serde(default = "default_theta")]
    pub theta: f64,
    /// Hot-spot parameter ρc (1: no hot spot).
    #[serde(default = "default_rho_c")]
    pub rho_c: f64,
}

fn default_k() -> f64 {
    0.75
}
fn default_theta() -> f64 {
    -0.1
}
fn default_rho_c() -> f64 {
    0.3
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MisregistrationDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    pub bands: Vec<BandShiftDesc>,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BandShiftDesc {
    pub band: String,
    #[serde(default)]
    pub shift_px: [f64; 2],
    #[serde(default)]
    pub rotation_deg: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RigParallaxDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    pub bands: Vec<BandOffsetDesc>,
    /// Write the band cameras into `transforms.json` as `rig_cameras` (rig-aware training); `false` leaves a
    /// dataset whose bands disagree by the parallax and says nothing about it, as a warped import would.
    #[serde(default = "yes")]
    pub write_rig_cameras: bool,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BandOffsetDesc {
    pub band: String,
    /// The band camera's centre in the frame camera's axes (OpenGL: +x right, +y up, +z backwards), metres.
    pub offset_m: [f64; 3],
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VignettingDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// [k1, k2, k3] (missing ones 0).
    pub coeffs: Vec<f64>,
    /// Centre in pixels; default: the image centre.
    #[serde(default)]
    pub center_px: Option<[f64; 2]>,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DriftDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Relative std of the per-view gain.
    #[serde(default)]
    pub std: f64,
    /// Relative std of an extra per-view, per-band gain.
    #[serde(default)]
    pub band_std: f64,
    /// Explicit per-view gains (cycled); replaces `std`.
    #[serde(default)]
    pub gains: Option<Vec<f64>>,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NoiseDesc {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Additive Gaussian std (reflectance units).
    #[serde(default)]
    pub std: f64,
    /// Signal-dependent variance per unit value (Poisson-like shot noise).
    #[serde(default)]
    pub shot: f64,
    /// Quantisation bits (0: none).
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// The value at the top DN.
    #[serde(default = "default_full_scale")]
    pub full_scale: f64,
}

fn default_bits() -> u32 {
    12
}
fn default_full_scale() -> f64 {
    1.0
}

impl EffectsDesc {
    /// Only the effects that are present and enabled.
    pub fn active(&self) -> EffectsDesc {
        EffectsDesc {
            sun: self.sun.clone().filter(|e| e.enabled),
            vegetation_brdf: self.vegetation_brdf.clone().filter(|e| e.enabled),
            misregistration: self.misregistration.clone().filter(|e| e.enabled),
            rig_parallax: self.rig_parallax.clone().filter(|e| e.enabled),
            vignetting: self.vignetting.clone().filter(|e| e.enabled),
            exposure_drift: self.exposure_drift.clone().filter(|e| e.enabled),
            noise: self.noise.clone().filter(|e| e.enabled),
        }
    }

    /// Names of the effects present (call on [`EffectsDesc::active`] for those that run).
    pub fn names(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        let flags = [
            (self.sun.is_some(), "sun"),
            (self.vegetation_brdf.is_some(), "vegetation_brdf"),
            (self.misregistration.is_some(), "misregistration"),
            (self.rig_parallax.is_some(), "rig_parallax"),
            (self.vignetting.is_some(), "vignetting"),
            (self.exposure_drift.is_some(), "exposure_drift"),
            (self.noise.is_some(), "noise"),
        ];
        for (on, n) in flags {
            if on {
                v.push(n);
            }
        }
        v
    }

    /// Range checks; errors are (key below `effects`, reason).
    pub fn validate(&self, scene: &SceneDesc) -> Result<(), (String, String)> {
        let bad = |k: &str, r: &str| Err((k.to_string(), r.to_string()));
        let fin = |v: f64| v.is_finite();
        if let Some(s) = &self.sun {
            if !(s.elevation_deg > 0.0 && s.elevation_deg <= 90.0) {
                return bad("sun.elevation_deg", "must be in (0, 90]");
            }
            if !fin(s.azimuth_deg) {
                return bad("sun.azimuth_deg", "must be finite");
            }
            if !(0.0..=1.0).contains(&s.sky_fraction) {
                return bad("sun.sky_fraction", "must be in [0, 1]");
            }
        }
        if let Some(b) = &self.vegetation_brdf {
            if !(b.k > 0.0 && b.k <= 2.0) {
                return bad("vegetation_brdf.k", "must be in (0, 2]");
            }
            if !(b.theta > -1.0 && b.theta < 1.0) {
                return bad("vegetation_brdf.theta", "must be in (-1, 1)");
            }
            if !(0.0..=2.0).contains(&b.rho_c) {
                return bad("vegetation_brdf.rho_c", "must be in [0, 2]");
            }
        }
        if let Some(m) = &self.misregistration {
            check_band_list(scene, "misregistration", m.bands.iter().map(|b| b.band.as_str()))?;
            for (i, s) in m.bands.iter().enumerate() {
                if !(fin(s.shift_px[0]) && fin(s.shift_px[1]) && fin(s.rotation_deg)) {
                    return Err((format!("misregistration.bands[{i}]"), "values must be finite".into()));
                }
            }
        }
        if let Some(r) = &self.rig_parallax {
            check_band_list(scene, "rig_parallax", r.bands.iter().map(|b| b.band.as_str()))?;
            for (i, o) in r.bands.iter().enumerate() {
                if !o.offset_m.iter().all(|v| v.is_finite() && v.abs() <= 5.0) {
                    return Err((
                        format!("rig_parallax.bands[{i}].offset_m"),
                        "three finite offsets of at most 5 m (a rig's lenses sit centimetres apart)".into(),
                    ));
                }
            }
            if r.enabled && self.misregistration.as_ref().is_some_and(|m| m.enabled) {
                return bad(
                    "rig_parallax",
                    "cannot be combined with misregistration (one kind of band offset per scene)",
                );
            }
        }
        if let Some(v) = &self.vignetting {
            if v.coeffs.len() > 3 || !v.coeffs.iter().all(|c| fin(*c)) {
                return bad("vignetting.coeffs", "up to three finite coefficients [k1, k2, k3]");
            }
        }
        if let Some(d) = &self.exposure_drift {
            if !(d.std >= 0.0 && d.band_std >= 0.0 && d.std < 1.0 && d.band_std < 1.0) {
                return bad("exposure_drift.std", "std and band_std must be in [0, 1)");
            }
            if let Some(g) = &d.gains {
                if g.is_empty() || !g.iter().all(|&x| x > 0.0 && x.is_finite()) {
                    return bad("exposure_drift.gains", "needs one or more positive gains");
                }
            }
        }
        if let Some(n) = &self.noise {
            if !(n.std >= 0.0 && n.shot >= 0.0 && n.std.is_finite() && n.shot.is_finite()) {
                return bad("noise.std", "std and shot must be >= 0");
            }
            if n.bits > 16 {
                return bad("noise.bits", "at most 16");
            }
            if !(n.full_scale > 0.0 && n.full_scale.is_finite()) {
                return bad("noise.full_scale", "must be positive");
            }
        }
        Ok(())
    }
}

/// An effect's per-band list (`{effect}.bands[i].band`): every name a band of the scene, none listed twice.
fn check_band_list<'a>(
    scene: &SceneDesc,
    effect: &str,
    bands: impl Iterator<Item = &'a str>,
) -> Result<(), (String, String)> {
    let names: Vec<String> = resolve_bands(scene).into_iter().map(|b| b.name).collect();
    let mut seen: Vec<&str> = Vec::new();
    for (i, band) in bands.enumerate() {
        let key = format!("{effect}.bands[{i}].band");
        if !names.iter().any(|n| n.eq_ignore_ascii_case(band)) {
            return Err((key, format!("unknown band `{band}` (bands: {})", names.join(", "))));
        }
        if seen.iter().any(|s| s.eq_ignore_ascii_case(band)) {
            return Err((key, "band listed twice".into()));
        }
        seen.push(band);
    }
    Ok(())
}

/// Unit vector towards the sun (x east, y north, z up).
pub fn sun_direction(s: &SunDesc) -> [f64; 3] {
    let (az, el) = (s.azimuth_deg.to_radians(), s.elevation_deg.to_radians());
    [el.cos() * az.sin(), el.cos() * az.cos(), el.sin()]
}

/// The sun-and-sky light factor L (module doc) for unit normal `n`, sun direction `s`, direct factor
/// `brdf` (1 for Lambertian) and visibility `vis`.
pub fn sun_sky_light(n: [f64; 3], s: [f64; 3], sky_fraction: f64, brdf: f64, visible: bool) -> f64 {
    let cos_i = DVec3::from(n).dot(DVec3::from(s));
    let direct = if visible && cos_i > 0.0 { brdf * cos_i / s[2] } else { 0.0 };
    (1.0 - sky_fraction) * direct + sky_fraction * (1.0 + n[2]) * 0.5
}

/// RPV factor relative to nadir view under zenith light (module doc). `n`, `l`, `v` unit vectors.
pub fn rpv_factor(b: &BrdfDesc, n: [f64; 3], l: [f64; 3], v: [f64; 3]) -> f64 {
    let (n, l, v) = (DVec3::from(n), DVec3::from(l), DVec3::from(v));
    let ci = n.dot(l).clamp(1e-6, 1.0);
    let cv = n.dot(v).clamp(1e-6, 1.0);
    let tl = l - ci * n;
    let tv = v - cv * n;
    // tanθ · (unit tangent) = t / cosθ.
    let g_big = (tl / ci - tv / cv).length();
    let cos_g = l.dot(v).clamp(-1.0, 1.0);
    rpv(b, ci, cv, cos_g, g_big) / rpv(b, 1.0, 1.0, 1.0, 0.0)
}

fn rpv(b: &BrdfDesc, ci: f64, cv: f64, cos_g: f64, g_big: f64) -> f64 {
    let m = (ci * cv).powf(b.k - 1.0) / (ci + cv).powf(1.0 - b.k);
    let t = b.theta;
    let f = (1.0 - t * t) / (1.0 + 2.0 * t * cos_g + t * t).powf(1.5);
    let h = 1.0 + (1.0 - b.rho_c) / (1.0 + g_big);
    m * f * h
}

/// Vignetting factor at image point (u, v) (pixels).
pub fn vignette(d: &VignettingDesc, width: u32, height: u32, u: f64, v: f64) -> f64 {
    let c = d.center_px.unwrap_or([width as f64 / 2.0, height as f64 / 2.0]);
    let half_diag = 0.5 * ((width as f64).powi(2) + (height as f64).powi(2)).sqrt();
    let r2 = ((u - c[0]).powi(2) + (v - c[1]).powi(2)) / (half_diag * half_diag);
    let k = |i: usize| d.coeffs.get(i).copied().unwrap_or(0.0);
    1.0 + r2 * (k(0) + r2 * (k(1) + r2 * k(2)))
}

/// Gain of (view, band) under exposure drift.
pub fn drift_gain(d: &DriftDesc, seed: u64, view: usize, band: usize) -> f64 {
    let g = match &d.gains {
        Some(g) => g[view % g.len()],
        None if d.std > 0.0 => 1.0 + d.std * normal(seed, STREAM_DRIFT, view as u64, 0),
        None => 1.0,
    };
    if d.band_std > 0.0 {
        g * (1.0 + d.band_std * normal(seed, STREAM_DRIFT_BAND, view as u64, band as u64))
    } else {
        g
    }
}

/// Adds noise to `value` and quantises it; returns (value, DN when quantised).
pub fn apply_noise(n: &NoiseDesc, value: f64, seed: u64, view: usize, band: usize, pixel: usize) -> (f64, Option<u16>) {
    let var = n.std * n.std + n.shot * value.max(0.0);
    let key = ((band as u64) << 40) | pixel as u64;
    let v = if var > 0.0 { value + var.sqrt() * normal(seed, STREAM_NOISE + view as u64, key, 1) } else { value };
    if n.bits == 0 {
        return (v, None);
    }
    let top = ((1u32 << n.bits) - 1) as f64;
    let dn = (v / n.full_scale * top).round().clamp(0.0, top);
    (dn / top * n.full_scale, Some(dn as u16))
}

const STREAM_DRIFT: u64 = 0x000d_41f7;
const STREAM_DRIFT_BAND: u64 = 0x000d_41f8;
const STREAM_NOISE: u64 = 0x4e01_5e00_0000;

/// splitmix64 finaliser.
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A counter-based hash of (seed, stream, a, b): the same inputs give the same bits on any thread.
pub fn hash4(seed: u64, stream: u64, a: u64, b: u64) -> u64 {
    mix(mix(mix(mix(seed) ^ stream) ^ a) ^ b)
}

/// A standard normal variate from the counter (Box-Muller on two hashed uniforms).
pub fn normal(seed: u64, stream: u64, a: u64, b: u64) -> f64 {
    let h1 = hash4(seed, stream, a, b.wrapping_mul(2));
    let h2 = hash4(seed, stream, a, b.wrapping_mul(2) + 1);
    let u1 = ((h1 >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let u2 = (h2 >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}
