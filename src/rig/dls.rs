//! The downwelling light sensors of MicaSense cameras, read as MicaSense's own library reads them
//! (micasense/imageprocessing `metadata.py`, `image.py`):
//!
//! - **Scale** (`irradiance_scale_factor`): tag values times `Camera:IrradianceScaleToSIUnits` are W/(m^2 nm); a
//!   file with a `HorizontalIrradiance` tag but no scale is a DLS2 file from firmware that left it out, scale 0.01;
//!   otherwise (DLS1) 1.
//! - **DLS2** ([`dls2`]): where the direct and scattered irradiance are both non-zero, the horizontal irradiance is
//!   the `HorizontalIrradiance` tag when the firmware computed it right (`horizontal_irradiance_valid`: RedEdge and
//!   RedEdge-M from 5.1.7, Altum from 1.2.3, RedEdge-P and Altum-PT always), else `direct sin(el) + scattered` with
//!   the sun's elevation computed from the capture's time and place (`compute_horizontal_irradiance_dls2`). The
//!   tags are read from both namespaces real files use, `DLS:` (micasense.com/DLS) and `Camera:` (Pix4D), as
//!   MicaSense's library (through exiftool's flat `XMP:` names) and OpenDroneMap do.
//! - **DLS1** ([`dls1`]): the spectral irradiance corrected for the sun's angle, below.
//!
//! DLS1 (MicaSense's first downwelling light sensor, RedEdge firmware 2.x): its `Camera:Irradiance` is the spectral
//! irradiance on the tilted sensor, not the horizontal irradiance reflectance needs. MicaSense's library turns it
//! into horizontal irradiance with the sun's position (micasense/imageprocessing `dls.py`, `image.py`); this is
//! the same model, written from its formulas:
//!
//! ```text
//! n_sun    = (cos el cos az, cos el sin az, -sin el)                     NED, az clockwise from north
//! n_sensor = Rz(yaw) Ry(pitch) Rx(roll) (0, 0, -1)                        DLS:Yaw/Pitch/Roll (radians, NED)
//! theta    = acos(n_sun . n_sensor)                                       sun-sensor angle
//! T(theta) = Fresnel transmission through air | 1.6 | 1.38 (unpolarised, Snell's law between layers)
//! E_direct = E_sensor / T(theta) / (1/6 + cos theta)                     direct-to-diffuse ratio 6
//! E_horiz  = E_direct sin el + E_direct / 6
//! ```
//!
//! The sun's elevation and azimuth come from NOAA's solar position equations (Meeus, "Astronomical Algorithms";
//! the NOAA Solar Calculator), good to about 0.01 degree for 1901-2099, with NOAA's refraction correction;
//! MicaSense uses pysolar. The time is EXIF `DateTimeOriginal` (+ `SubSecTimeOriginal`), which MicaSense cameras
//! write in UTC, and the position the EXIF GPS fix.

use super::calib::BandFile;
use super::error::RigError;

const NS_DLS: &str = "micasense.com/DLS";
const NS_CAMERA: &str = "pix4d.com";
/// MicaSense's assumed ratio of direct to diffuse irradiance.
pub const DIRECT_TO_DIFFUSE: f64 = 6.0;

/// A UTC calendar time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UtcTime {
    pub year: i32,
    pub month: u32,
    pub day: u32,
    pub hour: u32,
    pub minute: u32,
    pub second: f64,
}

impl UtcTime {
    /// Parses EXIF's `YYYY:MM:DD HH:MM:SS` with an optional `.fraction` (as `meta` joins `SubSecTimeOriginal`).
    pub fn from_exif(s: &str) -> Option<UtcTime> {
        let (date, time) = s.trim().split_once(' ')?;
        let d: Vec<&str> = date.split(':').collect();
        let t: Vec<&str> = time.split(':').collect();
        if d.len() != 3 || t.len() != 3 {
            return None;
        }
        let u = UtcTime {
            year: d[0].parse().ok()?,
            month: d[1].parse().ok()?,
            day: d[2].parse().ok()?,
            hour: t[0].parse().ok()?,
            minute: t[1].parse().ok()?,
            second: t[2].parse().ok()?,
        };
        let ok = (1..=12).contains(&u.month)
            && (1..=31).contains(&u.day)
            && u.hour < 24
            && u.minute < 60
            && (0.0..61.0).contains(&u.second);
        ok.then_some(u)
    }

    /// Julian day (Meeus ch. 7, Gregorian calendar).
    pub fn julian_day(&self) -> f64 {
        let (mut y, mut m) = (self.year as f64, self.month as f64);
        if m <= 2.0 {
            y -= 1.0;
            m += 12.0;
        }
        let a = (y / 100.0).floor();
        let b = 2.0 - a + (a / 4.0).floor();
        let frac = (self.hour as f64 + (self.minute as f64 + self.second / 60.0) / 60.0) / 24.0;
        (365.25 * (y + 4716.0)).floor() + (30.6001 * (m + 1.0)).floor() + self.day as f64 + frac + b - 1524.5
    }
}

/// The sun's (elevation, azimuth) in radians at a place and time: elevation above the horizon with refraction,
/// azimuth clockwise from north.
pub fn solar_position(lat_deg: f64, lon_deg: f64, t: &UtcTime) -> (f64, f64) {
    let (sin, cos, rad, deg) =
        (|x: f64| x.to_radians().sin(), |x: f64| x.to_radians().cos(), f64::to_radians, f64::to_degrees);
    let jc = (t.julian_day() - 2_451_545.0) / 36_525.0;
    let l0 = (280.46646 + jc * (36000.76983 + jc * 0.0003032)).rem_euclid(360.0);
    let m = 357.52911 + jc * (35999.05029 - 0.0001537 * jc);
    let e = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc);
    let c = sin(m) * (1.914602 - jc * (0.004817 + 0.000014 * jc))
        + sin(2.0 * m) * (0.019993 - 0.000101 * jc)
        + sin(3.0 * m) * 0.000289;
    let omega = 125.04 - 1934.136 * jc;
    let lambda = l0 + c - 0.00569 - 0.00478 * sin(omega);
    let eps0 = 23.0 + (26.0 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60.0) / 60.0;
    let eps = eps0 + 0.00256 * cos(omega);
    let decl = deg((sin(eps) * sin(lambda)).asin());
    let y = (rad(eps) / 2.0).tan().powi(2);
    let eq_time = 4.0
        * deg(y * sin(2.0 * l0) - 2.0 * e * sin(m) + 4.0 * e * y * sin(m) * cos(2.0 * l0)
            - 0.5 * y * y * sin(4.0 * l0)
            - 1.25 * e * e * sin(2.0 * m));
    let minutes = (t.hour as f64) * 60.0 + t.minute as f64 + t.second / 60.0;
    let tst = (minutes + eq_time + 4.0 * lon_deg).rem_euclid(1440.0);
    let ha = if tst / 4.0 < 0.0 { tst / 4.0 + 180.0 } else { tst / 4.0 - 180.0 };
    let zenith = deg((sin(lat_deg) * sin(decl) + cos(lat_deg) * cos(decl) * cos(ha)).clamp(-1.0, 1.0).acos());
    let az_term = ((sin(lat_deg) * cos(zenith) - sin(decl)) / (cos(lat_deg) * sin(zenith))).clamp(-1.0, 1.0);
    let az = if ha > 0.0 {
        (deg(az_term.acos()) + 180.0).rem_euclid(360.0)
    } else {
        (540.0 - deg(az_term.acos())).rem_euclid(360.0)
    };
    let el = 90.0 - zenith;
    let tan_el = rad(el).tan();
    let refraction = if el > 85.0 {
        0.0
    } else if el > 5.0 {
        58.1 / tan_el - 0.07 / tan_el.powi(3) + 0.000086 / tan_el.powi(5)
    } else if el > -0.575 {
        1735.0 + el * (-518.2 + el * (103.4 + el * (-12.79 + el * 0.711)))
    } else {
        -20.772 / tan_el
    } / 3600.0;
    (rad(el + refraction), rad(az))
}

/// The sun's direction in NED from its elevation and azimuth (radians).
pub fn sun_ned(el: f64, az: f64) -> [f64; 3] {
    [el.cos() * az.cos(), el.cos() * az.sin(), -el.sin()]
}

/// The DLS's normal (its body -z axis) in NED for a yaw, pitch, roll (radians, ZYX).
pub fn sensor_ned(yaw: f64, pitch: f64, roll: f64) -> [f64; 3] {
    let v = [0.0, roll.sin(), -roll.cos()]; // Rx (0, 0, -1)
    let v = [pitch.cos() * v[0] + pitch.sin() * v[2], v[1], -pitch.sin() * v[0] + pitch.cos() * v[2]]; // Ry
    [yaw.cos() * v[0] - yaw.sin() * v[1], yaw.sin() * v[0] + yaw.cos() * v[1], v[2]]
    // Rz
}

/// Unpolarised Fresnel transmission from index n1 into n2 at incidence `phi` (0 when total reflection).
fn fresnel_transmission(phi: f64, n1: f64, n2: f64) -> f64 {
    let f1 = phi.cos();
    let s = n1 / n2 * phi.sin();
    if s.abs() >= 1.0 {
        return 0.0;
    }
    let f2 = (1.0 - s * s).sqrt();
    let rs = ((n1 * f1 - n2 * f2) / (n1 * f1 + n2 * f2)).powi(2);
    let rp = ((n1 * f2 - n2 * f1) / (n1 * f2 + n2 * f1)).powi(2);
    let t = 1.0 - 0.5 * rs - 0.5 * rp;
    if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The DLS diffuser's transmission at sun-sensor angle `phi`: air (1.000277) into 1.6 into 1.38, the angle refracted
/// into each layer.
pub fn fresnel(phi: f64) -> f64 {
    let n = [1.000277, 1.6, 1.38];
    let mut phi_eff = phi;
    let mut t = 1.0;
    for w in n.windows(2) {
        phi_eff = (phi_eff.sin() / w[0]).asin();
        t *= fresnel_transmission(phi_eff, w[0], w[1]);
    }
    t
}

/// What the DLS1 correction found for one band file.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Dls1 {
    pub spectral_irradiance: f64,
    pub sun_sensor_angle: f64,
    pub solar_elevation: f64,
    pub solar_azimuth: f64,
    pub direct: f64,
    pub scattered: f64,
    pub horizontal: f64,
}

/// The capture's UTC time for the sun's position: refused when missing, malformed, or from an unset clock.
fn capture_time(m: &super::meta::FileMeta, why: &str) -> Result<UtcTime, RigError> {
    let dt = m.datetime.as_deref().ok_or_else(|| RigError::missing(&m.path, "DateTimeOriginal", why))?;
    if !m.clock_set {
        return Err(RigError::bad(
            &m.path,
            "DateTimeOriginal",
            format!("`{dt}`: the camera's clock was not set (no GPS time), so the sun's position is unknown ({why})"),
        ));
    }
    UtcTime::from_exif(dt)
        .ok_or_else(|| RigError::bad(&m.path, "DateTimeOriginal", format!("`{dt}` is not YYYY:MM:DD HH:MM:SS")))
}

/// A light-sensor tag from either namespace real files use (`DLS:` first, then Pix4D's `Camera:`).
fn dls_tag(b: &BandFile, tag: &str) -> Option<f64> {
    b.meta.xmp.number(NS_DLS, tag).or_else(|| b.meta.xmp.number(NS_CAMERA, tag))
}

/// Tag units -> W/(m^2 nm) (MicaSense `irradiance_scale_factor`) and where the factor came from.
pub fn irradiance_scale(b: &BandFile) -> Result<(f64, &'static str), RigError> {
    if let Some(v) = dls_tag(b, "IrradianceScaleToSIUnits") {
        if !(v > 0.0 && v.is_finite()) {
            return Err(RigError::bad(
                &b.meta.path,
                "Camera:IrradianceScaleToSIUnits",
                format!("{v}: not a positive scale"),
            ));
        }
        return Ok((v, "Camera:IrradianceScaleToSIUnits"));
    }
    if dls_tag(b, "HorizontalIrradiance").is_some() {
        return Ok((
            0.01,
            "0.01, assumed for DLS2 files without Camera:IrradianceScaleToSIUnits (as MicaSense's library does)",
        ));
    }
    Ok((1.0, "1 (DLS1)"))
}

/// Whether the firmware of `model` at version `software` (EXIF Software, `v5.1.7`) wrote a trustworthy
/// `HorizontalIrradiance` (MicaSense `horizontal_irradiance_valid`). Unknown versions of the models with the known
/// bug are not trusted (the direct and scattered irradiance give the value either way).
pub fn horizontal_irradiance_valid(model: Option<&str>, software: Option<&str>) -> bool {
    let good = match model {
        Some("RedEdge") | Some("RedEdge-M") => [5, 1, 7],
        Some("Altum") => [1, 2, 3],
        _ => return true,
    };
    let Some(v) = software else { return false };
    let parts: Vec<Option<u64>> =
        v.trim().trim_start_matches(['v', 'V']).split('.').map(|p| p.trim().parse().ok()).collect();
    if parts.is_empty() || parts.iter().any(Option::is_none) {
        return false;
    }
    let n: Vec<u64> = parts.into_iter().flatten().collect();
    [0, 1, 2].map(|i| n.get(i).copied().unwrap_or(0)) >= good
}

/// What a DLS2 band file gave.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Dls2 {
    /// W/(m^2 nm).
    pub horizontal: f64,
    pub direct: f64,
    pub scattered: f64,
    pub scale: f64,
    pub scale_source: &'static str,
    /// "HorizontalIrradiance", or how it was recomputed.
    pub source: String,
}

/// Horizontal irradiance of a DLS2 file (module doc); `None` when the file carries no DLS2 irradiance (no
/// non-zero direct and scattered irradiance, and no trusted horizontal one).
pub fn dls2(b: &BandFile) -> Result<Option<Dls2>, RigError> {
    let m = &b.meta;
    let (scale, scale_source) = irradiance_scale(b)?;
    let horizontal = dls_tag(b, "HorizontalIrradiance");
    let direct = dls_tag(b, "DirectIrradiance").unwrap_or(0.0);
    let scattered = dls_tag(b, "ScatteredIrradiance").unwrap_or(0.0);
    let valid = horizontal.is_some() && horizontal_irradiance_valid(m.model.as_deref(), m.software.as_deref());
    let out = |h: f64, source: String| Dls2 {
        horizontal: h,
        direct: direct * scale,
        scattered: scattered * scale,
        scale,
        scale_source,
        source,
    };
    if direct != 0.0 && scattered != 0.0 {
        if let (true, Some(h)) = (valid, horizontal) {
            return Ok(Some(out(h * scale, "DLS:HorizontalIrradiance".into())));
        }
        // The firmware's horizontal value is not trusted: direct and scattered with the sun's elevation.
        let why = "the firmware's HorizontalIrradiance is not trusted, and recomputing it from the direct and \
                   scattered irradiance needs the sun's elevation (or give --panel)";
        let gps = m.gps.ok_or_else(|| RigError::missing(&m.path, "GPSLatitude / GPSLongitude", why))?;
        let t = capture_time(m, why)?;
        let (el, _) = solar_position(gps.latitude, gps.longitude, &t);
        let h = (direct * el.sin() + scattered) * scale;
        let firmware = m.software.as_deref().unwrap_or("unknown");
        return Ok(Some(out(
            h,
            format!(
                "DirectIrradiance sin(el) + ScatteredIrradiance, el = {:.2} deg from the time and place (firmware {firmware} of the {} predates a trustworthy HorizontalIrradiance)",
                el.to_degrees(),
                m.model.as_deref().unwrap_or("camera")
            ),
        )));
    }
    match (valid, horizontal) {
        (true, Some(h)) if h > 0.0 => Ok(Some(out(h * scale, "HorizontalIrradiance".into()))),
        _ => Ok(None),
    }
}

/// Horizontal irradiance from a DLS1 band file (errors name the file and the missing tag).
pub fn dls1(b: &BandFile) -> Result<Dls1, RigError> {
    let m = &b.meta;
    let x = &m.xmp;
    let why = "the DLS1 sun-angle correction needs it (or give --panel)";
    let (scale, _) = irradiance_scale(b)?;
    let spectral = x
        .number(NS_CAMERA, "Irradiance")
        .or_else(|| x.number(NS_DLS, "SpectralIrradiance"))
        .filter(|v| *v > 0.0)
        .map(|v| v * scale)
        .ok_or_else(|| RigError::missing(&m.path, "Camera:Irradiance", why))?;
    let angle = |tag: &str| x.number(NS_DLS, tag).ok_or_else(|| RigError::missing(&m.path, &format!("DLS:{tag}"), why));
    let (yaw, pitch, roll) = (angle("Yaw")?, angle("Pitch")?, angle("Roll")?);
    let gps = m.gps.ok_or_else(|| RigError::missing(&m.path, "GPSLatitude / GPSLongitude", why))?;
    let t = capture_time(m, why)?;
    let (el, az) = solar_position(gps.latitude, gps.longitude, &t);
    let (s, n) = (sun_ned(el, az), sensor_ned(yaw, pitch, roll));
    let theta = (s[0] * n[0] + s[1] * n[1] + s[2] * n[2]).clamp(-1.0, 1.0).acos();
    let diffuse = 1.0 / DIRECT_TO_DIFFUSE;
    if el <= 0.0 || diffuse + theta.cos() < 0.05 {
        return Err(RigError::bad(
            &m.path,
            "DLS:Yaw/Pitch/Roll",
            format!(
                "the sun is {:.1} deg above the horizon and {:.1} deg from the sensor's normal: no DLS1 correction \
                 holds there (give --panel)",
                el.to_degrees(),
                theta.to_degrees()
            ),
        ));
    }
    let direct = spectral / fresnel(theta) / (diffuse + theta.cos());
    let scattered = direct * diffuse;
    Ok(Dls1 {
        spectral_irradiance: spectral,
        sun_sensor_angle: theta,
        solar_elevation: el,
        solar_azimuth: az,
        direct,
        scattered,
        horizontal: direct * el.sin() + scattered,
    })
}
