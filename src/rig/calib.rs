//! Vendor conventions: turns a file's tags ([`super::meta::FileMeta`]) into the numbers the radiometric chain,
//! the lens model and the registration need ([`BandFile`]), naming the file and tag of anything missing.
//!
//! Conventions (docs/radiometry.md has the sources):
//! - **MicaSense** (RedEdge, Altum, RedEdge-MX/P, Dual): `MicaSense:CaptureId`, `MicaSense:RadiometricCalibration`
//!   (a1, a2, a3), black level = mean of EXIF BlackLevel (else of `DarkRowValue`), exposure from EXIF in seconds,
//!   gain = ISO / 100, vignetting `Camera:VignettingCenter` + `VignettingPolynomial` dividing the signal,
//!   intrinsics `Camera:PerspectiveFocalLength` (px, or mm when `PerspectiveFocalLengthUnits` says so or the
//!   value is below 100) and `PrincipalPoint` (mm, times the focal-plane resolution), `PerspectiveDistortion`
//!   (k1, k2, k3, p1, p2); the light sensor's tags are read by [`super::dls`].
//! - **DJI** P4 Multispectral / Mavic 3M (`drone-dji:` attributes): `CaptureUUID`, exposure `ExposureTime` in
//!   microseconds, gain `SensorGain`, `SensorGainAdjustment` multiplying, vignetting `VignettingData` (k0..k5)
//!   about `CalibratedOpticalCenterX/Y` *multiplying* the signal, intrinsics from `DewarpData`
//!   ("date;fx,fy,cx,cy,k1,k2,p1,p2,k3", cx/cy relative to the calibrated optical centre), irradiance `Irradiance`.
//! - **Generic** Pix4D-camera rigs (e.g. MS600Pro files with `Camera:BandName` and `CentralWavelength`): band
//!   identity, exposure and gain from EXIF, no absolute calibration: relative radiance, reflectance from a panel.
//! - Without an XMP camera model, EXIF FocalLength x FocalPlaneXResolution gives a pinhole (centre principal point).

use super::error::RigError;
use super::meta::FileMeta;

const NS_MICASENSE: &str = "micasense.com/MicaSense";
const NS_CAMERA: &str = "pix4d.com";
const NS_DJI: &str = "dji.com";

/// Which convention a file follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Vendor {
    MicaSense,
    Dji,
    Generic,
}

impl Vendor {
    pub fn name(self) -> &'static str {
        match self {
            Vendor::MicaSense => "MicaSense",
            Vendor::Dji => "DJI",
            Vendor::Generic => "generic Pix4D-XMP rig",
        }
    }
}

/// Whether the vignetting polynomial divides (MicaSense, Pix4D) or multiplies (DJI) the signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum VignettingMode {
    Divide,
    Multiply,
}

/// Pinhole + Brown-Conrady intrinsics in pixels (OpenCV's model).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Lens {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub p1: f64,
    pub p2: f64,
}

/// Everything the chain needs about one band file.
#[derive(Debug, Clone)]
pub struct BandFile {
    pub meta: FileMeta,
    pub vendor: Vendor,
    /// Camera make/model/vendor as one string, for the "mixed cameras" check.
    pub camera: String,
    pub capture_key: String,
    pub band_name: String,
    pub center_nm: f64,
    pub fwhm_nm: Option<f64>,
    pub black_level: f64,
    pub exposure_s: f64,
    pub gain: f64,
    /// MicaSense a1, a2, a3 (a1 = None: relative radiance).
    pub radiometric: Option<[f64; 3]>,
    pub gain_adjustment: f64,
    pub vignetting_center: Option<[f64; 2]>,
    pub vignetting_poly: Vec<f64>,
    pub vignetting_mode: VignettingMode,
    pub lens: Option<Lens>,
    /// Rig rotation relative to the reference camera in degrees (roll, pitch, yaw as MicaSense writes them).
    pub rig_relatives: Option<[f64; 3]>,
    /// `Camera:RigTranslations`: the camera's centre relative to the rig's reference camera (metres, taken in the
    /// reference camera's axes: x right, y down, z forward; MicaSense's library reads the tag but does not use it).
    pub rig_translations: Option<[f64; 3]>,
    /// DJI: optical-centre offset to the reference band in pixels.
    pub relative_center: Option<[f64; 2]>,
    /// DJI's sun-sensor `Irradiance` (its own units). MicaSense's light sensor is read by [`super::dls`].
    pub irradiance: Option<f64>,
}

/// Bands centred above this (nm) are thermal (MicaSense Altum's LWIR at 11000 nm): not reflectance.
pub const THERMAL_FROM_NM: f64 = 2500.0;

fn need<T>(v: Option<T>, m: &FileMeta, tag: &str, why: &str) -> Result<T, RigError> {
    v.ok_or_else(|| RigError::missing(&m.path, tag, why))
}

/// Parses "840(+/-26)nm" (DJI BandFreq) into (centre, FWHM = twice the half width).
fn band_freq(s: &str) -> Option<(f64, Option<f64>)> {
    let digits: String = s.chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    let center = digits.parse::<f64>().ok()?;
    let half = s.split("+/-").nth(1).and_then(|r| {
        r.chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect::<String>().parse::<f64>().ok()
    });
    Some((center, half.map(|h| 2.0 * h)))
}

/// Interprets one file's tags.
pub fn interpret(meta: FileMeta) -> Result<BandFile, RigError> {
    let x = &meta.xmp;
    let vendor = if x.has_namespace(NS_MICASENSE) {
        Vendor::MicaSense
    } else if x.has_namespace(NS_DJI) {
        Vendor::Dji
    } else if x.text(NS_CAMERA, "BandName").is_some() || x.number(NS_CAMERA, "CentralWavelength").is_some() {
        Vendor::Generic
    } else {
        let read = format!(
            "make {:?}, model {:?}, {} XMP",
            meta.make.as_deref().unwrap_or("?"),
            meta.model.as_deref().unwrap_or("?"),
            if x.has_namespace("") { "some" } else { "no" }
        );
        return Err(RigError::UnknownVendor {
            path: meta.path.clone(),
            read,
            missing: "XMP band identity (Camera:BandName / CentralWavelength, MicaSense: or drone-dji: tags)".into(),
        });
    };
    if meta.samples_per_pixel != 1 {
        return Err(RigError::bad(&meta.path, "SamplesPerPixel", "raw rig files have one band per file"));
    }
    let camera =
        format!("{} {} {}", vendor.name(), meta.make.as_deref().unwrap_or(""), meta.model.as_deref().unwrap_or(""));

    // Band identity: never from the file name.
    let dji_freq = x.text(NS_DJI, "BandFreq").and_then(band_freq);
    let band_name = x.text(NS_CAMERA, "BandName").or_else(|| x.text(NS_DJI, "BandName")).map(str::to_string);
    let band_name = need(band_name, &meta, "Camera:BandName", "band identity")?;
    let center_nm = x.number(NS_CAMERA, "CentralWavelength").or(dji_freq.map(|f| f.0));
    let center_nm = need(center_nm, &meta, "Camera:CentralWavelength", "bands are ordered by wavelength")?;
    let fwhm_nm = x.number(NS_CAMERA, "WavelengthFWHM").or(dji_freq.and_then(|f| f.1));
    if center_nm > THERMAL_FROM_NM {
        return Err(RigError::Thermal { path: meta.path.clone(), band: band_name, center_nm });
    }

    let capture_key = match vendor {
        Vendor::MicaSense => x.text(NS_MICASENSE, "CaptureId"),
        Vendor::Dji => x.text(NS_DJI, "CaptureUUID").or_else(|| x.text(NS_CAMERA, "CaptureUUID")),
        Vendor::Generic => x.text(NS_CAMERA, "CaptureUUID"),
    }
    .map(str::to_string)
    .or_else(|| meta.datetime.clone().map(|t| format!("time {t}")));
    let capture_key = need(
        capture_key,
        &meta,
        "MicaSense:CaptureId / drone-dji:CaptureUUID / Camera:CaptureUUID / DateTimeOriginal",
        "groups the bands of one trigger",
    )?;

    let black_level = match (&meta.black_level, x.numbers(NS_MICASENSE, "DarkRowValue")) {
        (Some(b), _) => b.iter().sum::<f64>() / b.len() as f64,
        (None, Some(d)) => d.iter().sum::<f64>() / d.len() as f64,
        (None, None) => return Err(RigError::missing(&meta.path, "BlackLevel (EXIF 50714)", "the dark offset")),
    };

    let (exposure_s, gain, gain_adjustment) = match vendor {
        Vendor::Dji => {
            let t = x.number(NS_DJI, "ExposureTime").map(|us| us * 1e-6).or(meta.exposure_s);
            let t = need(t, &meta, "drone-dji:ExposureTime", "exposure (microseconds)")?;
            let g = need(x.number(NS_DJI, "SensorGain"), &meta, "drone-dji:SensorGain", "sensor gain")?;
            (t, g, x.number(NS_DJI, "SensorGainAdjustment").unwrap_or(1.0))
        }
        _ => {
            let t = need(meta.exposure_s, &meta, "ExposureTime (EXIF)", "exposure")?;
            let iso = need(meta.iso, &meta, "ISOSpeed / PhotographicSensitivity (EXIF)", "gain = ISO/100")?;
            (t, iso / 100.0, 1.0)
        }
    };
    if exposure_s.is_nan() || gain.is_nan() || exposure_s <= 0.0 || gain <= 0.0 {
        return Err(RigError::bad(
            &meta.path,
            "ExposureTime / gain",
            format!("{exposure_s} s, gain {gain}: not positive"),
        ));
    }

    let radiometric = match vendor {
        Vendor::MicaSense => {
            let a = x.numbers(NS_MICASENSE, "RadiometricCalibration");
            let a = need(a, &meta, "MicaSense:RadiometricCalibration", "a1, a2, a3 of the radiance model")?;
            if a.len() != 3 {
                return Err(RigError::bad(&meta.path, "MicaSense:RadiometricCalibration", "expected 3 values"));
            }
            Some([a[0], a[1], a[2]])
        }
        _ => None,
    };

    let (vignetting_center, vignetting_poly, vignetting_mode) = match vendor {
        Vendor::Dji => {
            let c = match (x.number(NS_DJI, "CalibratedOpticalCenterX"), x.number(NS_DJI, "CalibratedOpticalCenterY")) {
                (Some(a), Some(b)) => Some([a, b]),
                _ => None,
            };
            (c, x.numbers(NS_DJI, "VignettingData").unwrap_or_default(), VignettingMode::Multiply)
        }
        _ => {
            let c = x.numbers(NS_CAMERA, "VignettingCenter").filter(|v| v.len() == 2).map(|v| [v[0], v[1]]);
            (c, x.numbers(NS_CAMERA, "VignettingPolynomial").unwrap_or_default(), VignettingMode::Divide)
        }
    };
    if !vignetting_poly.is_empty() && vignetting_center.is_none() {
        return Err(RigError::missing(&meta.path, "VignettingCenter", "the vignetting polynomial needs its centre"));
    }
    if vignetting_poly.len() > 8 {
        return Err(RigError::bad(&meta.path, "VignettingPolynomial", "more than 8 coefficients"));
    }

    let lens = lens(vendor, &meta)?.or_else(|| exif_lens(&meta));
    if let Some(l) = &lens {
        check_lens(l, vendor, &meta)?;
    }
    let rig_relatives = x.numbers(NS_CAMERA, "RigRelatives").filter(|v| v.len() == 3).map(|v| [v[0], v[1], v[2]]);
    let rig_translations = match x.numbers(NS_CAMERA, "RigTranslations") {
        None => None,
        Some(v) if v.len() == 3 && v.iter().all(|t| t.is_finite() && t.abs() <= 0.5) => Some([v[0], v[1], v[2]]),
        Some(v) => {
            return Err(RigError::bad(
                &meta.path,
                "Camera:RigTranslations",
                format!(
                "{v:?}: expected three offsets in metres, each at most 0.5 m (a rig's lenses sit centimetres apart)"
            ),
            ))
        }
    };
    let relative_center = match (x.number(NS_DJI, "RelativeOpticalCenterX"), x.number(NS_DJI, "RelativeOpticalCenterY"))
    {
        (Some(a), Some(b)) => Some([a, b]),
        _ => None,
    };
    let irradiance = match vendor {
        Vendor::Dji => x.number(NS_DJI, "Irradiance"),
        _ => None,
    };
    Ok(BandFile {
        vendor,
        camera,
        capture_key,
        band_name,
        center_nm,
        fwhm_nm,
        black_level,
        exposure_s,
        gain,
        radiometric,
        gain_adjustment,
        vignetting_center,
        vignetting_poly,
        vignetting_mode,
        lens,
        rig_relatives,
        rig_translations,
        relative_center,
        irradiance,
        meta,
    })
}

/// A pinhole from EXIF alone (FocalLength times FocalPlaneXResolution, principal point at the image centre, no
/// distortion) for rigs whose XMP has no camera model: a starting point that SfM refines (`import poses`).
fn exif_lens(meta: &FileMeta) -> Option<Lens> {
    let f = meta.focal_length_mm? * meta.focal_plane_x_res_per_mm?;
    let (cx, cy) = ((meta.width as f64 - 1.0) / 2.0, (meta.height as f64 - 1.0) / 2.0);
    Some(Lens { fx: f, fy: f, cx, cy, k1: 0.0, k2: 0.0, k3: 0.0, p1: 0.0, p2: 0.0 })
}

/// A lens whose numbers would make a camera of no use (a focal length that is not positive or gives a field of
/// view of almost 180° or 0°, a principal point that is not a number): refused, naming the file and the tag.
fn check_lens(l: &Lens, vendor: Vendor, meta: &FileMeta) -> Result<(), RigError> {
    let tag = match vendor {
        Vendor::Dji => "drone-dji:DewarpData",
        _ if meta.xmp.number(NS_CAMERA, "PerspectiveFocalLength").is_some() => "Camera:PerspectiveFocalLength",
        _ => "FocalLength (EXIF)",
    };
    for f in [l.fx, l.fy] {
        if let Some(why) = crate::data::transforms::implausible_focal(f, meta.width as f64, meta.height as f64) {
            return Err(RigError::bad(&meta.path, tag, why));
        }
    }
    let all = [l.cx, l.cy, l.k1, l.k2, l.k3, l.p1, l.p2];
    if !all.iter().all(|v| v.is_finite()) {
        return Err(RigError::bad(&meta.path, tag, format!("the lens model holds a value that is not finite: {l:?}")));
    }
    Ok(())
}

fn lens(vendor: Vendor, meta: &FileMeta) -> Result<Option<Lens>, RigError> {
    let x = &meta.xmp;
    match vendor {
        Vendor::Dji => {
            let Some(d) = x.text(NS_DJI, "DewarpData") else { return Ok(None) };
            let nums: Vec<f64> = d
                .split(';')
                .nth(1)
                .unwrap_or(d)
                .split(',')
                .map(|s| s.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| RigError::bad(&meta.path, "drone-dji:DewarpData", format!("not numbers: {d:?}")))?;
            if nums.len() != 9 {
                return Err(RigError::bad(
                    &meta.path,
                    "drone-dji:DewarpData",
                    "expected date;fx,fy,cx,cy,k1,k2,p1,p2,k3",
                ));
            }
            let (ox, oy) =
                match (x.number(NS_DJI, "CalibratedOpticalCenterX"), x.number(NS_DJI, "CalibratedOpticalCenterY")) {
                    (Some(a), Some(b)) => (a, b),
                    _ => (meta.width as f64 / 2.0, meta.height as f64 / 2.0),
                };
            Ok(Some(Lens {
                fx: nums[0],
                fy: nums[1],
                cx: ox + nums[2],
                cy: oy + nums[3],
                k1: nums[4],
                k2: nums[5],
                p1: nums[6],
                p2: nums[7],
                k3: nums[8],
            }))
        }
        _ => {
            let Some(f) = x.number(NS_CAMERA, "PerspectiveFocalLength") else { return Ok(None) };
            let res = meta.focal_plane_x_res_per_mm;
            let units_mm = match x.text(NS_CAMERA, "PerspectiveFocalLengthUnits") {
                Some(u) => u.eq_ignore_ascii_case("mm"),
                None => f < 100.0,
            };
            let need_res = || need(res, meta, "FocalPlaneXResolution (EXIF)", "converts millimetres to pixels");
            let f_px = if units_mm { f * need_res()? } else { f };
            let pp = x.numbers(NS_CAMERA, "PrincipalPoint").filter(|v| v.len() == 2);
            let pp = need(pp, meta, "Camera:PrincipalPoint", "the lens model")?;
            let r = need_res()?;
            let d = x.numbers(NS_CAMERA, "PerspectiveDistortion").unwrap_or_default();
            if !d.is_empty() && d.len() != 5 {
                return Err(RigError::bad(&meta.path, "Camera:PerspectiveDistortion", "expected k1,k2,k3,p1,p2"));
            }
            let g = |i: usize| d.get(i).copied().unwrap_or(0.0);
            Ok(Some(Lens {
                fx: f_px,
                fy: f_px,
                cx: pp[0] * r,
                cy: pp[1] * r,
                k1: g(0),
                k2: g(1),
                k3: g(2),
                p1: g(3),
                p2: g(4),
            }))
        }
    }
}
