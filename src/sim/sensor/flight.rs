//! [`simulate_raw_rig`]: a scene's flight as the camera writes it, into a folder that is renamed into place only
//! when complete:
//!
//! ```text
//! OUT/card/                    what the camera's card holds (MicaSense: 0000SET/000/IMG_0000_1.tif ...;
//!                              DJI: DJI_001/DJI_0011.TIF ...): a calibration-panel capture first (IMG_0000),
//!                              then the flight, then (optionally) a second panel capture
//! OUT/truth/flight.json        the camera as simulated, every capture's true pose, the GPS written and its error
//!                              (noise and the datum shift), exposures, true and recorded irradiance
//! OUT/truth/panel.json         the panel's reflectance per band (its calibration sheet)
//! OUT/truth/dataset/           the same flight written directly by the simulator (reflectance, the reference
//!                              band's pinhole camera, depth, ground_truth.ply, truth DSM and ortho)
//! OUT/README.md                the layout and the conventions
//! ```
//!
//! Every band of a capture is rendered through its own camera: each raw pixel is undistorted with the band's
//! lens, rotated by the rig (`RigRelatives`) into the reference camera, cast from the band's centre
//! (`RigTranslations`) into the scene, and its radiance `L = value · E_b · drift / π` (value: reflectance times
//! the scene's light, as every simulated image) becomes a DN through [`super::forward`].

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde_json::json;

use super::forward::{quantise, radiance_to_dn, undistort, RigPose};
use super::light::{auto_exposure, band_irradiance, dls_reading, horizontal_irradiance_trusted};
use super::profile::{SensorKind, SensorProfile, Vendor};
use super::tags::{write_band_file, written_exposure, GpsTag, Shot};
use crate::geo::Projector;
use crate::rig::dls::UtcTime;
use crate::sim::effects::{hash4, normal};
use crate::sim::render::Prepared;
use crate::sim::scene::{BandDesc, SceneDesc};
use crate::sim::writer::{write_json, StagingDir};
use crate::sim::{SimError, SimOptions};

/// Options of a raw flight.
#[derive(Debug, Clone)]
pub struct RawRigOptions {
    pub sensor: SensorKind,
    /// Sensor size (same field of view); default the camera's own. One of the two keeps the aspect.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Number of flight captures (spread over the scene's camera groups).
    pub views: Option<usize>,
    pub seed: Option<u64>,
    pub threads: usize,
    pub overwrite: bool,
    /// GPS noise per capture, standard deviation (horizontal per axis, vertical), metres.
    pub gps_noise_m: [f64; 2],
    /// A constant GPS offset for the whole flight (east, north, up; metres): the datum shift of an uncorrected
    /// receiver, which no method without ground control can know.
    pub gps_shift_m: [f64; 3],
    /// UTC time of the first capture, EXIF form `YYYY:MM:DD HH:MM:SS`.
    pub start: String,
    /// Seconds between captures.
    pub interval_s: f64,
    /// Firmware version written (default: the camera's; MicaSense firmware older than the version that writes a
    /// trustworthy horizontal irradiance writes a wrong `HorizontalIrradiance`, as it did).
    pub firmware: Option<String>,
    /// A second panel capture after the flight.
    pub panel_after: bool,
    /// Ground-truth points of the truth dataset.
    pub points: usize,
    /// Ground control points surveyed and clicked in the images, written as `gcp_list.txt` ([`super::gcp`]);
    /// 0: none.
    pub gcp: usize,
}

impl Default for RawRigOptions {
    fn default() -> Self {
        RawRigOptions {
            sensor: SensorKind::MicasenseRededge,
            width: None,
            height: None,
            views: None,
            seed: None,
            threads: 0,
            overwrite: false,
            gps_noise_m: DEFAULT_GPS_NOISE_M,
            gps_shift_m: DEFAULT_GPS_SHIFT_M,
            start: DEFAULT_START.into(),
            gcp: 0,
            interval_s: 2.0,
            firmware: None,
            panel_after: false,
            points: 200_000,
        }
    }
}

/// A consumer receiver's scatter per fix (horizontal per axis, vertical), metres.
pub const DEFAULT_GPS_NOISE_M: [f64; 2] = [0.5, 0.8];
/// The flight's datum shift (east, north, up), metres.
pub const DEFAULT_GPS_SHIFT_M: [f64; 3] = [0.6, -0.4, 0.9];
/// A midsummer morning, UTC.
pub const DEFAULT_START: &str = "2025:06:14 09:30:00";

/// What was written.
#[derive(Debug, Clone)]
pub struct RawRigReport {
    pub out: PathBuf,
    pub sensor: SensorKind,
    pub captures: usize,
    pub panel_captures: usize,
    pub width: u32,
    pub height: u32,
    pub bands: usize,
    pub files: usize,
    pub seconds: f64,
}

impl std::fmt::Display for RawRigReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} flight captures + {} panel capture(s) as a {} ({}x{} px, {} bands), {} files in card/, truth in truth/; {:.1} s",
            self.out.display(),
            self.captures,
            self.panel_captures,
            self.sensor.name(),
            self.width,
            self.height,
            self.bands,
            self.files,
            self.seconds
        )
    }
}

/// Effects the sensor models itself.
const SENSOR_EFFECTS: [&str; 4] = ["vignetting", "noise", "misregistration", "rig_parallax"];

/// One capture to write.
#[derive(Debug, Clone)]
struct Plan {
    /// Capture number on the card (IMG_0000 is the first).
    number: usize,
    /// Index into the flight's views; `None` for a panel capture.
    view: Option<usize>,
    time: UtcTime,
}

fn add_seconds(t: &UtcTime, s: f64) -> UtcTime {
    // Whole days are not crossed by a flight; minutes and hours roll over.
    let total = t.hour as f64 * 3600.0 + t.minute as f64 * 60.0 + t.second + s;
    let total = total.rem_euclid(86_400.0);
    let hour = (total / 3600.0).floor();
    let minute = ((total - hour * 3600.0) / 60.0).floor();
    UtcTime { hour: hour as u32, minute: minute as u32, second: total - hour * 3600.0 - minute * 60.0, ..*t }
}

fn exif_time(t: &UtcTime) -> (String, String) {
    let whole = t.second.floor();
    let sub = ((t.second - whole) * 1e6).round().min(999_999.0) as u64;
    (
        format!("{:04}:{:02}:{:02} {:02}:{:02}:{:02}", t.year, t.month, t.day, t.hour, t.minute, whole as u32),
        format!("{sub:06}"),
    )
}

/// An identifier of `n` letters and digits from a seeded hash (MicaSense's CaptureId and FlightId look like this).
fn ident(seed: u64, stream: u64, i: u64, n: usize) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789";
    (0..n).map(|k| A[(hash4(seed, stream, i, k as u64) % A.len() as u64) as usize] as char).collect()
}

/// The card's path of a capture's band file (relative to `card/`).
pub fn band_file(profile: &SensorProfile, number: usize, suffix: u32) -> String {
    match profile.vendor {
        Vendor::MicaSense => format!("0000SET/{:03}/IMG_{number:04}_{suffix}.tif", number / 200),
        Vendor::Dji => format!("DJI_001/DJI_{number:03}{suffix}.TIF"),
    }
}

/// Heading of a pose's view (degrees clockwise from grid north): the horizontal part of the viewing direction, or
/// of the image's up direction when looking straight down.
fn heading_deg(c2w: &[[f64; 4]; 4]) -> f64 {
    let fwd = [-c2w[0][2], -c2w[1][2]];
    let up = [c2w[0][1], c2w[1][1]];
    let v = if fwd[0].hypot(fwd[1]) > 1e-3 { fwd } else { up };
    v[0].atan2(v[1]).to_degrees()
}

/// The scene as the sensor sees it: its bands replaced by the camera's reflective bands.
fn sensor_scene(desc: &SceneDesc, profile: &SensorProfile) -> Result<SceneDesc, SimError> {
    let bad = |key: &str, reason: String| SimError::Scene { file: desc.source.clone(), key: key.into(), reason };
    for name in SENSOR_EFFECTS {
        let on = match name {
            "vignetting" => desc.effects.vignetting.as_ref().is_some_and(|e| e.enabled),
            "noise" => desc.effects.noise.as_ref().is_some_and(|e| e.enabled),
            "misregistration" => desc.effects.misregistration.as_ref().is_some_and(|e| e.enabled),
            _ => desc.effects.rig_parallax.as_ref().is_some_and(|e| e.enabled),
        };
        if on {
            return Err(bad(
                &format!("effects.{name}"),
                format!(
                    "--raw-rig {} simulates the camera's own {name}; leave the effect out of a scene flown with a raw rig",
                    profile.kind.name()
                ),
            ));
        }
    }
    match &desc.crs {
        Some(_) => {}
        None => {
            return Err(bad(
                "crs",
                "--raw-rig writes GPS positions: the scene needs a projected `crs` and its `world_offset`".into(),
            ))
        }
    }
    let mut d = desc.clone();
    d.band_range = None;
    d.bands = Some(
        by_wavelength(profile)
            .into_iter()
            .map(|i| &profile.bands[i])
            .map(|b| BandDesc {
                name: b.name.to_string(),
                center_nm: b.center_nm,
                fwhm_nm: Some(b.fwhm_nm),
                response: None,
            })
            .collect(),
    );
    let r = &profile.bands[profile.reference].lens;
    d.image.width = profile.width;
    d.image.height = profile.height;
    d.image.hfov_deg = 2.0 * (profile.width as f64 / 2.0 / r.fx).atan().to_degrees();
    Ok(d)
}

/// The camera's band indices in wavelength order (the order of the scene's bands and of every dataset).
pub fn by_wavelength(profile: &SensorProfile) -> Vec<usize> {
    let mut order: Vec<usize> = (0..profile.bands.len()).collect();
    order.sort_by(|&a, &b| profile.bands[a].center_nm.total_cmp(&profile.bands[b].center_nm));
    order
}

/// Per band: the undistorted normalised direction of every raw pixel (row-major), shared by every capture.
fn ray_tables(profile: &SensorProfile) -> Vec<Vec<[f64; 2]>> {
    let (w, h) = (profile.width as usize, profile.height as usize);
    profile
        .bands
        .iter()
        .map(|b| {
            let l = &b.lens;
            (0..w * h)
                .map(|i| {
                    let (u, v) = ((i % w) as f64, (i / w) as f64);
                    let (x, y) = undistort(l, (u - l.cx) / l.fx, (v - l.cy) / l.fy);
                    [x, y]
                })
                .collect()
        })
        .collect()
}

const STREAM_GPS: u64 = 0x0067_7053;
const STREAM_EXPOSURE: u64 = 0x0065_7870;
const STREAM_DLS: u64 = 0x0064_6c73;
const STREAM_ATTITUDE: u64 = 0x0061_7474;
const STREAM_PIXEL: u64 = 0x7069_7800_0000;

/// Everything the capture loop shares.
struct Ctx<'a> {
    profile: &'a SensorProfile,
    prep: &'a Prepared,
    projector: &'a Projector,
    tables: Vec<Vec<[f64; 2]>>,
    rig: Vec<RigPose>,
    /// Per camera band: its index among the scene's bands (wavelength order).
    scene_band: Vec<usize>,
    /// Per band: irradiance (W/(m^2 nm)) and the base exposure and ISO.
    irradiance: Vec<f64>,
    exposure: Vec<(f64, u32)>,
    panel_exposure: Vec<(f64, u32)>,
    sky_fraction: f64,
    firmware_ok: bool,
    flight_id: String,
    opts: &'a RawRigOptions,
    seed: u64,
    card: PathBuf,
    home: [f64; 3],
}

/// The camera-to-world pose (world frame) of the reference camera of a flight view.
fn world_pose(prep: &Prepared, v: usize) -> [[f64; 4]; 4] {
    let mut m = prep.poses[v];
    for (r, o) in m.iter_mut().zip(prep.world_offset) {
        r[3] += o;
    }
    m
}

impl Ctx<'_> {
    /// The written GPS fix of a camera at world position `p`, capture `n`: the datum shift and noise added.
    fn gps(&self, p: [f64; 3], n: usize) -> Result<(GpsTag, [f64; 3]), SimError> {
        let o = &self.opts;
        let e = [
            o.gps_shift_m[0] + o.gps_noise_m[0] * normal(self.seed, STREAM_GPS, n as u64, 0),
            o.gps_shift_m[1] + o.gps_noise_m[0] * normal(self.seed, STREAM_GPS, n as u64, 1),
            o.gps_shift_m[2] + o.gps_noise_m[1] * normal(self.seed, STREAM_GPS, n as u64, 2),
        ];
        let q = [p[0] + e[0], p[1] + e[1], p[2] + e[2]];
        let g = self
            .projector
            .to_geodetic(q)
            .map_err(|err| SimError::Option { key: "raw-rig".into(), reason: format!("GPS of capture {n}: {err}") })?;
        Ok((GpsTag { latitude: g[0], longitude: g[1], altitude: g[2] }, e))
    }

    /// Renders one band of a flight view to container DNs.
    fn render_band(&self, view: usize, bi: usize, number: usize, exposure_s: f64, gain: f64) -> Vec<u16> {
        let p = self.profile;
        let b = &p.bands[bi];
        let (w, h) = (p.width as usize, p.height as usize);
        let c2w = self.prep.poses[view];
        let rig = &self.rig[bi];
        let (sun, brdf) = self.prep.light_model();
        let e = self.irradiance[bi] * self.prep.gain(view, self.scene_band[bi]);
        let table = &self.tables[bi];
        let gl = |v: glam::DVec3| [v.x, -v.y, -v.z];
        let rot = |q: [f64; 3]| [0, 1, 2].map(|i| c2w[i][0] * q[0] + c2w[i][1] * q[1] + c2w[i][2] * q[2]);
        let oc = rot(gl(rig.center));
        let origin = [c2w[0][3] + oc[0], c2w[1][3] + oc[1], c2w[2][3] + oc[2]];
        let mut out = vec![0u16; w * h];
        for (i, px) in out.iter_mut().enumerate() {
            let [x, y] = table[i];
            let d = rot(gl(rig.ref_from_band * glam::DVec3::new(x, y, 1.0)));
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let d = d.map(|c| c / n);
            let (hit, light) = self.prep.shade(origin, d, sun, brdf);
            let value = self.prep.materials[hit.material].refl[self.scene_band[bi]] * light;
            let l = value * e / std::f64::consts::PI;
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let dn = radiance_to_dn(p, b, self.radiance_units(l, bi), u, v, exposure_s, gain);
            *px = quantise(p, dn, self.seed, STREAM_PIXEL + number as u64, ((bi as u64) << 40) | i as u64);
        }
        out
    }

    /// Radiance in the units the camera's model expects: absolute for MicaSense, DJI's relative units (the sun
    /// sensor's `Irradiance` units) for DJI.
    fn radiance_units(&self, l: f64, _bi: usize) -> f64 {
        match self.profile.vendor {
            Vendor::MicaSense => l,
            Vendor::Dji => l * self.profile.dji_irradiance_units,
        }
    }

    /// Renders one band of a calibration-panel capture: the panel (its sheet's reflectance) on dark ground, seen
    /// straight down from about a metre, lit by the flight's first light.
    fn render_panel(&self, bi: usize, number: usize, exposure_s: f64, gain: f64) -> Vec<u16> {
        let p = self.profile;
        let b = &p.bands[bi];
        let (w, h) = (p.width as usize, p.height as usize);
        let quad = panel_quad(w, h);
        let ordered = crate::rig::panel::order_corners(quad);
        let e = self.irradiance[bi] * self.prep.gain(0, self.scene_band[bi]);
        let mut out = vec![0u16; w * h];
        for (i, px) in out.iter_mut().enumerate() {
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let rho = if crate::rig::panel::in_quad(&ordered, u, v) {
                b.panel_reflectance
            } else {
                // Asphalt-like ground with a coarse pattern, so the only uniform bright patch is the panel.
                0.09 * (1.0 + 0.3 * ((u / 9.0).sin() * (v / 13.0).cos()))
                    * (1.0 + 0.1 * normal(self.seed, 0x9a7e1, i as u64, 0))
            };
            let l = rho * e / std::f64::consts::PI;
            let dn = radiance_to_dn(p, b, self.radiance_units(l, bi), u, v, exposure_s, gain);
            *px = quantise(p, dn, self.seed, STREAM_PIXEL + number as u64, ((bi as u64) << 40) | i as u64);
        }
        out
    }

    /// Writes one capture (every band, and the thermal band where the camera has one); returns its truth record.
    fn write_capture(&self, plan: &Plan) -> Result<serde_json::Value, SimError> {
        let p = self.profile;
        let o = self.opts;
        let n = plan.number as u64;
        let (pose, pos) = match plan.view {
            Some(v) => {
                let m = world_pose(self.prep, v);
                (Some(m), [m[0][3], m[1][3], m[2][3]])
            }
            None => (None, [self.home[0], self.home[1], self.prep.world_offset[2] + 1.2]),
        };
        let (gps, gps_error) = self.gps(pos, plan.number)?;
        let heading = pose.map_or(0.0, |m| heading_deg(&m));
        let conv = self.projector.convergence_deg(gps.latitude, gps.longitude).unwrap_or(0.0);
        let att = [
            heading + conv + 0.5 * normal(self.seed, STREAM_ATTITUDE, n, 0),
            1.5 * normal(self.seed, STREAM_ATTITUDE, n, 1),
            1.5 * normal(self.seed, STREAM_ATTITUDE, n, 2),
        ];
        let ypr = [att[0].to_radians(), att[1].to_radians(), att[2].to_radians()];
        let (datetime, subsec) = exif_time(&plan.time);
        let capture_id = match p.vendor {
            Vendor::MicaSense => ident(self.seed, 0xc4b7, n, 20),
            Vendor::Dji => {
                let hx = |k: u64| format!("{:016x}", hash4(self.seed, 0xd1, n, k));
                let (a, b) = (hx(0), hx(1));
                format!("{}{}", &a[..16], &b[..16])
            }
        };
        let mut bands_truth = Vec::new();
        let mut files = Vec::new();
        for (bi, b) in p.bands.iter().enumerate() {
            let base = if plan.view.is_some() { self.exposure[bi] } else { self.panel_exposure[bi] };
            let jitter = 1.0 + 0.03 * normal(self.seed, STREAM_EXPOSURE, n, bi as u64);
            let t = written_exposure(base.0 * jitter);
            let gain = base.1 as f64 / 100.0;
            let px = match plan.view {
                Some(v) => self.render_band(v, bi, plan.number, t, gain),
                None => self.render_panel(bi, plan.number, t, gain),
            };
            let horizontal = self.irradiance[bi] * self.prep.gain(plan.view.unwrap_or(0), self.scene_band[bi]);
            let measured = horizontal * (1.0 + 0.005 * normal(self.seed, STREAM_DLS, n, bi as u64));
            let dls = dls_reading(
                measured,
                self.sky_fraction,
                gps.latitude,
                gps.longitude,
                &plan.time,
                ypr,
                self.firmware_ok,
            );
            let dark = p.black_level
                + p.read_noise_dn * (1u64 << p.adc_shift) as f64 / 35.0 * normal(self.seed, 0xda7c, n, bi as u64);
            let shot = Shot {
                profile: p,
                band: Some(b),
                width: p.width,
                height: p.height,
                capture_id: capture_id.clone(),
                flight_id: self.flight_id.clone(),
                datetime: datetime.clone(),
                subsec: subsec.clone(),
                gps: Some(gps),
                attitude_deg: att,
                exposure_s: t,
                iso: base.1,
                dark_rows: [dark; 4],
                dls: Some(dls),
                boot_ms: 400_000 + (o.interval_s * 1000.0) as u64 * n,
            };
            let rel = band_file(p, plan.number, b.suffix);
            let path = self.card.join(&rel);
            write_band_file(&path, &shot, &px, self.relative_center(bi)).map_err(SimError::io(&path))?;
            files.push(rel);
            bands_truth.push(json!({
                "band": b.name, "exposure_s": t, "iso": base.1, "irradiance": horizontal,
                "dls_horizontal": measured, "dls": dls,
            }));
        }
        if let (Some(th), Some(v)) = (p.thermal, plan.view) {
            let rel = band_file(p, plan.number, th.suffix);
            let path = self.card.join(&rel);
            let px = self.render_thermal(v, th.width as usize, th.height as usize);
            let shot = Shot {
                profile: p,
                band: None,
                width: th.width,
                height: th.height,
                capture_id: capture_id.clone(),
                flight_id: self.flight_id.clone(),
                datetime,
                subsec,
                gps: Some(gps),
                attitude_deg: att,
                exposure_s: 1.0 / 30.0,
                iso: 100,
                dark_rows: [0.0; 4],
                dls: None,
                boot_ms: 400_000 + (o.interval_s * 1000.0) as u64 * n,
            };
            write_band_file(&path, &shot, &px, [0.0; 2]).map_err(SimError::io(&path))?;
            files.push(rel);
        }
        Ok(json!({
            "number": plan.number,
            "kind": if plan.view.is_some() { "flight" } else { "panel" },
            "view": plan.view,
            "capture_id": capture_id,
            "files": files,
            "time": format!("{}.{}", exif_time(&plan.time).0, exif_time(&plan.time).1),
            "reference_c2w": pose,
            "gps_written": gps,
            "gps_error_m": gps_error,
            "attitude_deg": att,
            "bands": bands_truth,
        }))
    }

    /// A coarse thermal image (centi-kelvin, as the Altum's LWIR band stores it) from the reference camera: the
    /// thermal band is written as the camera writes it; msnerf does not train on it.
    fn render_thermal(&self, view: usize, w: usize, h: usize) -> Vec<u16> {
        let c2w = self.prep.poses[view];
        let k = crate::sim::cameras::intrinsics(w as u32, h as u32, 57.0);
        let (sun, brdf) = self.prep.light_model();
        let rows = [c2w[0], c2w[1], c2w[2]];
        let ki: crate::data::camera::Intrinsics<f64> = k.intrinsics();
        let nb = self.profile.bands.len();
        (0..w * h)
            .map(|i| {
                let ray = crate::data::camera::generate_ray(&ki, &rows, (i / w) as f64 + 0.5, (i % w) as f64 + 0.5);
                let (hit, _) = self.prep.shade(ray.origin, ray.direction, sun, brdf);
                let r = &self.prep.materials[hit.material].refl;
                // Vegetation (bright in NIR against red) is cooler than dry surfaces.
                let ndvi = (r[nb - 1] - r[2]) / (r[nb - 1] + r[2]).max(1e-6);
                ((305.0 - 12.0 * ndvi.clamp(-1.0, 1.0)) * 100.0) as u16
            })
            .collect()
    }

    /// DJI's `RelativeOpticalCenterX/Y`: where a far point on the reference (NIR) camera's axis lands in the band,
    /// relative to the band's principal point, in pixels (msnerf's importer adds the difference of two bands'
    /// values to the reference band's pixels).
    fn relative_center(&self, bi: usize) -> [f64; 2] {
        let r = &self.rig[bi];
        let d = r.ref_from_band.transpose() * glam::DVec3::Z;
        let l = &self.profile.bands[bi].lens;
        [l.fx * d.x / d.z, l.fy * d.y / d.z]
    }
}

/// The calibration panel's corners in a panel capture (raw pixels): a square a third of the image high, turned
/// by 5 degrees, right of the centre.
pub fn panel_quad(w: usize, h: usize) -> crate::rig::panel::Quad {
    let (cx, cy) = (0.55 * w as f64, 0.5 * h as f64);
    let half = h as f64 / 6.0;
    let (s, c) = 5f64.to_radians().sin_cos();
    [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]
        .map(|[x, y]| [cx + half * (c * x - s * y), cy + half * (s * x + c * y)])
}

/// The camera (resized and with the firmware the options ask for), the scene prepared for it (the camera's bands,
/// the reference band's field of view) and the options the truth dataset is simulated with. The same inputs give
/// the same flight, so tests and benchmarks rebuild the truth's geometry with this.
pub fn prepare(
    desc: &SceneDesc,
    opts: &RawRigOptions,
) -> Result<(SensorProfile, SceneDesc, Prepared, SimOptions), SimError> {
    let opt_err = |key: &str, reason: String| SimError::Option { key: key.into(), reason };
    let mut profile = SensorProfile::new(opts.sensor);
    let (w, h) = match (opts.width, opts.height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (w, ((w as f64 * profile.height as f64 / profile.width as f64).round() as u32).max(1)),
        (None, Some(h)) => (((h as f64 * profile.width as f64 / profile.height as f64).round() as u32).max(1), h),
        (None, None) => (profile.width, profile.height),
    };
    if !(32..=8192).contains(&w) || !(32..=8192).contains(&h) {
        return Err(opt_err("width", format!("a raw rig's sensor of {w}x{h} px: each side must be 32..=8192")));
    }
    if (w, h) != (profile.width, profile.height) {
        profile = profile.scaled(w, h);
    }
    if let Some(f) = &opts.firmware {
        profile.firmware = f.clone();
    }
    let sdesc = sensor_scene(desc, &profile)?;
    let sim_opts = SimOptions {
        width: Some(w),
        height: Some(h),
        views: opts.views,
        seed: opts.seed,
        threads: opts.threads,
        points: opts.points,
        overwrite: true,
        ..SimOptions::default()
    };
    let prep = Prepared::new(&sdesc, &sim_opts)?;
    Ok((profile, sdesc, prep, sim_opts))
}

/// Simulates `desc` flown with a raw rig into `out` (see the module doc). Fails before writing on bad options.
pub fn simulate_raw_rig(desc: &SceneDesc, opts: &RawRigOptions, out: &Path) -> Result<RawRigReport, SimError> {
    let t0 = Instant::now();
    let opt_err = |key: &str, reason: String| SimError::Option { key: key.into(), reason };
    for (k, v) in [("gps-noise", opts.gps_noise_m.to_vec()), ("gps-shift", opts.gps_shift_m.to_vec())] {
        if v.iter().any(|x| !x.is_finite() || x.abs() > 1000.0) || (k == "gps-noise" && v.iter().any(|x| *x < 0.0)) {
            return Err(opt_err(k, format!("{v:?}: metres, finite, at most 1000 (noise not negative)")));
        }
    }
    if opts.gcp > 100 {
        return Err(opt_err("gcp", format!("{} control points: at most 100", opts.gcp)));
    }
    if !(opts.interval_s > 0.0 && opts.interval_s <= 3600.0) {
        return Err(opt_err("capture-interval", format!("{} s: must be in (0, 3600]", opts.interval_s)));
    }
    let start = UtcTime::from_exif(&opts.start)
        .ok_or_else(|| opt_err("start-time", format!("`{}` is not YYYY:MM:DD HH:MM:SS (UTC)", opts.start)))?;
    let (profile, sdesc, prep, sim_opts) = prepare(desc, opts)?;
    let (w, h) = (profile.width, profile.height);
    let crs = prep.crs.clone().expect("sensor_scene checked the crs");
    let projector = Projector::new(&crs).map_err(|e| SimError::Scene {
        file: desc.source.clone(),
        key: "crs".into(),
        reason: e.to_string(),
    })?;
    let nv = prep.poses.len();
    let home_local = prep.poses.first().map_or([0.0; 3], |m| [m[0][3], m[1][3], 0.0]);
    let home = [home_local[0] + prep.world_offset[0], home_local[1] + prep.world_offset[1], prep.world_offset[2]];
    let home_geo = projector.to_geodetic(home).map_err(|e| opt_err("raw-rig", e.to_string()))?;
    let (el, _) = crate::rig::dls::solar_position(home_geo[0], home_geo[1], &start);
    if el.to_degrees() < 10.0 {
        return Err(opt_err(
            "start-time",
            format!(
                "the sun is {:.1} deg above the horizon at {} over the scene ({:.4} N, {:.4} E): fly in daylight",
                el.to_degrees(),
                opts.start,
                home_geo[0],
                home_geo[1]
            ),
        ));
    }
    let seed = prep.seed;
    let irradiance: Vec<f64> = profile.bands.iter().map(band_irradiance).collect();
    let order = by_wavelength(&profile);
    let scene_band = |bi: usize| order.iter().position(|&o| o == bi).expect("a permutation");
    let max_gain = |bi: usize| (0..nv).map(|v| prep.gain(v, scene_band(bi))).fold(1.0, f64::max);
    let units = |e: f64| if profile.vendor == Vendor::Dji { e * profile.dji_irradiance_units } else { e };
    let exposure: Vec<(f64, u32)> = profile
        .bands
        .iter()
        .enumerate()
        .map(|(bi, b)| auto_exposure(&profile, b, units(0.6 * irradiance[bi] * max_gain(bi) / std::f64::consts::PI)))
        .collect();
    let panel_exposure: Vec<(f64, u32)> = profile
        .bands
        .iter()
        .enumerate()
        .map(|(bi, b)| {
            auto_exposure(
                &profile,
                b,
                units(0.6 * irradiance[bi] * prep.gain(0, scene_band(bi)) / std::f64::consts::PI),
            )
        })
        .collect();
    let threads = if opts.threads == 0 {
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    } else {
        opts.threads
    };

    let stage = StagingDir::new(out, opts.overwrite)?;
    let root = stage.path.clone();
    let card = root.join("card");
    let mut plans = vec![Plan { number: 0, view: None, time: add_seconds(&start, -90.0) }];
    plans.extend((0..nv).map(|v| Plan {
        number: v + 1,
        view: Some(v),
        time: add_seconds(&start, opts.interval_s * v as f64),
    }));
    if opts.panel_after {
        plans.push(Plan { number: nv + 1, view: None, time: add_seconds(&start, opts.interval_s * nv as f64 + 60.0) });
    }
    for pl in &plans {
        for b in &profile.bands {
            if let Some(parent) = card.join(band_file(&profile, pl.number, b.suffix)).parent() {
                std::fs::create_dir_all(parent).map_err(SimError::io(parent))?;
            }
        }
    }
    let ctx = Ctx {
        profile: &profile,
        prep: &prep,
        projector: &projector,
        tables: ray_tables(&profile),
        rig: profile.bands.iter().map(|b| RigPose::of(&profile, b)).collect(),
        scene_band: {
            let order = by_wavelength(&profile);
            (0..profile.bands.len()).map(|bi| order.iter().position(|&o| o == bi).expect("a permutation")).collect()
        },
        irradiance: irradiance.clone(),
        exposure,
        panel_exposure,
        sky_fraction: prep.effects.sun.as_ref().map_or(0.15, |s| s.sky_fraction),
        firmware_ok: profile.vendor == Vendor::Dji || horizontal_irradiance_trusted(profile.model, &profile.firmware),
        flight_id: ident(seed, 0xf11, 0, 20),
        opts,
        seed,
        card: card.clone(),
        home,
    };
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let first_err: Mutex<Option<SimError>> = Mutex::new(None);
    let records: Mutex<Vec<Option<serde_json::Value>>> = Mutex::new(vec![None; plans.len()]);
    std::thread::scope(|s| {
        for _ in 0..threads.min(plans.len()).max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= plans.len() || failed.load(Ordering::Relaxed) {
                    break;
                }
                match ctx.write_capture(&plans[i]) {
                    Ok(r) => records.lock().expect("no panics while held")[i] = Some(r),
                    Err(e) => {
                        failed.store(true, Ordering::Relaxed);
                        first_err.lock().expect("no panics while held").get_or_insert(e);
                    }
                }
            });
        }
    });
    if let Some(e) = first_err.into_inner().expect("threads joined") {
        return Err(e);
    }
    let records: Vec<serde_json::Value> = records.into_inner().expect("threads joined").into_iter().flatten().collect();
    let files: usize = records.iter().map(|r| r["files"].as_array().map_or(0, |f| f.len())).sum();

    // The truth: the same flight written directly by the simulator, the camera, every capture, the panel.
    let mut tdesc = sdesc.clone();
    tdesc.effects.exposure_drift = None;
    let truth = root.join("truth");
    std::fs::create_dir_all(&truth).map_err(SimError::io(&truth))?;
    // With SfM-like points (0.1 m of noise, tracks of 3 views or more), as structure from motion brings them.
    let sparse = crate::sim::sparse::SparseOptions { count: 600 * nv, noise_m: 0.1, min_views: 3 };
    crate::sim::simulate(
        &tdesc,
        &SimOptions { overwrite: false, sparse_points: Some(sparse), ..sim_opts },
        &truth.join("dataset"),
    )?;
    super::truth::write_flight_truth(&truth, &profile, opts, desc, &crs, &prep, &irradiance, &records)?;
    // The scene as simulated, so the truth's geometry can be rebuilt from the flight folder alone.
    let scene_text =
        match crate::sim::scene::BUILTIN_SCENES.iter().find(|(n, _)| desc.source == format!("built-in scene `{n}`")) {
            Some((_, text)) => text.to_string(),
            None => std::fs::read_to_string(&desc.source).map_err(SimError::io(&desc.source))?,
        };
    std::fs::write(truth.join("scene.yaml"), scene_text).map_err(SimError::io(truth.join("scene.yaml")))?;
    write_json(
        &truth.join("panel.json"),
        &json!({
            "note": "the calibration panel's reflectance per band, as its calibration sheet gives it",
            "bands": profile.bands.iter().map(|b| json!({"band": b.name, "center_nm": b.center_nm, "reflectance": b.panel_reflectance})).collect::<Vec<_>>(),
            "panel_captures": records.iter().filter(|r| r["kind"] == "panel").map(|r| r["number"].clone()).collect::<Vec<_>>(),
            "corners_px": panel_quad(profile.width as usize, profile.height as usize),
        }),
    )?;
    if opts.gcp > 0 {
        let points = super::gcp::place(&prep, opts.gcp, seed)?;
        let captures: Vec<(usize, usize)> = plans.iter().filter_map(|p| Some((p.number, p.view?))).collect();
        let file = |number: usize, bi: usize| {
            let f = band_file(&profile, number, profile.bands[bi].suffix);
            crate::geo::gcp::image_base_name(&f).to_string()
        };
        let (list, exact) = super::gcp::observations(&prep, &profile, &captures, &points, seed, &file);
        super::gcp::write(&root, &list, &exact)?;
    }
    super::truth::write_readme(&root, &profile, opts, desc, nv)?;
    stage.commit()?;
    Ok(RawRigReport {
        out: out.to_path_buf(),
        sensor: opts.sensor,
        captures: nv,
        panel_captures: plans.len() - nv,
        width: w,
        height: h,
        bands: profile.bands.len(),
        files,
        seconds: t0.elapsed().as_secs_f64(),
    })
}
