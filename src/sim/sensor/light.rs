//! The light a raw flight is taken under: a clear-sky spectral irradiance at the ground integrated per band, the
//! light sensor's readings per capture (DLS2: horizontal, direct and scattered irradiance and the sun's position;
//! DJI: one irradiance in its own units) and the auto-exposure that keeps the brightest surfaces below saturation.
//!
//! The spectrum is a 5778 K black body scaled to 1.45 W/(m^2 nm) at 550 nm with a Rayleigh-like loss towards the
//! blue (`1 - 0.25 (450/λ)^4`): the shape and size of a clear midday sky's global horizontal irradiance, which is all
//! the radiometric chain needs (reflectance is radiance over irradiance; the spectrum's fine structure cancels).
//! Changes of the light over the flight (clouds) are the scene's `exposure_drift` gains, applied to the irradiance;
//! the light sensor records them, a panel taken before the flight does not.

use super::profile::{BandCamera, SensorProfile, Vendor};
use super::tags::DlsReading;
use crate::rig::dls::{fresnel, sensor_ned, solar_position, sun_ned, UtcTime};
use crate::sim::spectra::{band_value, Response, Spectrum};

/// Global horizontal spectral irradiance of the model sky at `nm` (W / (m^2 nm)).
pub fn solar_irradiance(nm: f64) -> f64 {
    let planck = |l: f64| {
        let l = l * 1e-9;
        1.0 / (l.powi(5) * ((1.438_777e-2 / (l * 5778.0)).exp() - 1.0))
    };
    1.45 * planck(nm) / planck(550.0) * (1.0 - 0.25 * (450.0 / nm).powi(4)) / (1.0 - 0.25 * (450.0f64 / 550.0).powi(4))
}

/// The band-integrated irradiance of [`solar_irradiance`] (Gaussian response of the band's centre and FWHM).
pub fn band_irradiance(b: &BandCamera) -> f64 {
    let knots: Vec<(f64, f64)> = (300..=1200).step_by(5).map(|nm| (nm as f64, solar_irradiance(nm as f64))).collect();
    let s = Spectrum::new(knots).expect("a valid table");
    band_value(&s, &Response::Gaussian { center_nm: b.center_nm, fwhm_nm: b.fwhm_nm })
}

/// Exposure (s) and ISO that put a radiance `l_bright` at 60 % of the ADC range above the dark level in the
/// image centre, the shutter kept at or below 2.5 ms by raising the gain (as the cameras' auto-exposure does).
pub fn auto_exposure(p: &SensorProfile, b: &BandCamera, l_bright: f64) -> (f64, u32) {
    let range = p.container_max() - p.black_level;
    let per_unit = match p.vendor {
        Vendor::MicaSense => 65536.0 / b.radiometric[0],
        Vendor::Dji => 65536.0 / b.gain_adjustment,
    };
    let mut iso = 100u32;
    let mut t = 0.6 * range / (l_bright * per_unit);
    while t > 2.5e-3 && iso < 800 {
        iso *= 2;
        t /= 2.0;
    }
    (t.max(5e-5), iso)
}

/// Versions from which MicaSense firmware writes a trustworthy `HorizontalIrradiance` (micasense
/// `Metadata.horizontal_irradiance_valid`): RedEdge and RedEdge-M 5.1.7, Altum 1.2.3; RedEdge-P and Altum-PT always.
pub fn horizontal_irradiance_trusted(model: &str, firmware: &str) -> bool {
    let good = match model {
        "RedEdge" | "RedEdge-M" => [5, 1, 7],
        "Altum" => [1, 2, 3],
        _ => return true,
    };
    let v: Vec<u64> = firmware.trim_start_matches('v').split('.').map(|s| s.trim().parse().unwrap_or(0)).collect();
    let v = [0, 1, 2].map(|i| v.get(i).copied().unwrap_or(0));
    v >= good
}

/// The light sensor's reading for one band of one capture. `horizontal`: the true horizontal irradiance
/// (W/(m^2 nm)); `sky_fraction`: its diffuse share; `ypr`: the sensor's attitude (radians, NED);
/// `firmware_ok`: whether the firmware computes the horizontal irradiance right (else the tag holds
/// direct + scattered, the kind of value early firmware wrote, and only the direct and scattered tags are right).
pub fn dls_reading(
    horizontal: f64,
    sky_fraction: f64,
    lat: f64,
    lon: f64,
    t: &UtcTime,
    ypr: [f64; 3],
    firmware_ok: bool,
) -> DlsReading {
    let (el, az) = solar_position(lat, lon, t);
    let scattered = sky_fraction * horizontal;
    let direct = (1.0 - sky_fraction) * horizontal / el.sin().max(0.05);
    let (s, n) = (sun_ned(el, az), sensor_ned(ypr[0], ypr[1], ypr[2]));
    let theta = (s[0] * n[0] + s[1] * n[1] + s[2] * n[2]).clamp(-1.0, 1.0).acos();
    let spectral = fresnel(theta) * (direct * theta.cos().max(0.0) + scattered);
    DlsReading {
        horizontal,
        direct,
        scattered,
        spectral,
        solar_elevation: el,
        solar_azimuth: az,
        ypr,
        firmware_horizontal: (!firmware_ok).then_some(direct + scattered),
    }
}
