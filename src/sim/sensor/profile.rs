//! The cameras `msnerf simulate --raw-rig` writes as: band sets, lenses, rig geometry, radiometric constants,
//! light sensors and file layouts of a MicaSense RedEdge-MX, a MicaSense Altum and a DJI Phantom 4 Multispectral.
//!
//! The values are representative of each model (sizes, band centres and widths, focal lengths and pixel pitches
//! from the makers' sheets; distortion, vignetting and radiometric coefficients of the magnitude real units write,
//! the MicaSense ones after the real RedEdge files in `tests/fixtures/real/`), not any one unit's calibration: a
//! user's camera writes its own numbers into its files, and the importer reads them from there.
//!
//! Conventions (the tags the profiles become are in [`super::tags`]):
//! - lens: OpenCV's Brown-Conrady model in pixels of the band's raw image (pixel centres at integers);
//! - rig rotation: MicaSense's `Camera:RigRelatives` (degrees, R = Rx Ry Rz, band camera -> rig); the band's rays
//!   in the reference camera are `R_ref^T R_band` times its own (micasense `Image.get_homography`);
//! - rig translation: `Camera:RigTranslations`, the band camera's centre in the reference camera's axes (x right,
//!   y down, z forward), metres;
//! - vignetting: MicaSense `VignettingCenter` + `VignettingPolynomial` k0..k5 in the raw pixel radius r, the signal
//!   divided by `1 + k0 r + ... + k5 r^6` (DJI: `VignettingData`, the signal multiplied by the same polynomial).

use crate::rig::calib::Lens;

/// The camera a raw flight is written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorKind {
    /// MicaSense RedEdge-MX (model tag `RedEdge-M`): 5 bands, 1280x960, 12-bit in 16, DLS2.
    MicasenseRededge,
    /// MicaSense Altum: 5 bands at 2064x1544 and a 160x120 thermal band, 12-bit in 16, DLS2.
    MicasenseAltum,
    /// DJI Phantom 4 Multispectral: 5 bands, 1600x1300, 16-bit, sun sensor `Irradiance`.
    DjiP4m,
}

impl SensorKind {
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::MicasenseRededge => "micasense-rededge",
            SensorKind::MicasenseAltum => "micasense-altum",
            SensorKind::DjiP4m => "dji-p4m",
        }
    }
}

/// How the maker writes radiometry and the light sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Vendor {
    MicaSense,
    Dji,
}

/// One spectral band camera of the rig.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BandCamera {
    pub name: &'static str,
    /// File-name suffix (MicaSense `_1`..`_5`) or DJI's last digit.
    pub suffix: u32,
    pub center_nm: f64,
    pub fwhm_nm: f64,
    pub lens: Lens,
    /// `Camera:RigRelatives`, degrees.
    pub rig_rotation_deg: [f64; 3],
    /// `Camera:RigTranslations`, metres in the reference camera's axes.
    pub rig_translation_m: [f64; 3],
    /// MicaSense a1, a2, a3 (radiance = ... a1 / 2^16; row gradient a2, a3). DJI: a1 = 1, a2 = a3 = 0.
    pub radiometric: [f64; 3],
    /// Vignetting centre (raw pixels) and polynomial k0..k5 in the pixel radius.
    pub vignetting_center: [f64; 2],
    pub vignetting_poly: [f64; 6],
    /// DJI `SensorGainAdjustment` (1 for MicaSense).
    pub gain_adjustment: f64,
    /// Reflectance of the calibration panel in this band (the panel's calibration sheet).
    pub panel_reflectance: f64,
}

/// A thermal band the camera writes beside the reflective ones (msnerf reads the reflective bands only).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct ThermalBand {
    pub suffix: u32,
    pub width: u32,
    pub height: u32,
}

/// A whole camera.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SensorProfile {
    pub kind: SensorKind,
    pub vendor: Vendor,
    pub make: &'static str,
    pub model: &'static str,
    pub firmware: String,
    pub width: u32,
    pub height: u32,
    /// Pixels per millimetre on the focal plane (EXIF FocalPlaneXResolution).
    pub focal_plane_px_per_mm: f64,
    /// Significant bits of a sample; MicaSense stores 12 bits shifted left by 4 in a 16-bit container.
    pub adc_bits: u32,
    /// Left shift of the ADC value in the 16-bit container.
    pub adc_shift: u32,
    /// Dark offset in container DN (EXIF BlackLevel).
    pub black_level: f64,
    /// Read noise in ADC DN and electrons per ADC DN (shot noise: variance = signal / e_per_dn).
    pub read_noise_dn: f64,
    pub electrons_per_dn: f64,
    pub f_number: f64,
    /// Index of the reference band (the rig's `RigRelativesReferenceRigCameraIndex`; DJI: NIR).
    pub reference: usize,
    /// Bands in file-suffix order.
    pub bands: Vec<BandCamera>,
    pub thermal: Option<ThermalBand>,
    /// `Camera:IrradianceScaleToSIUnits`: written when `Some` (DLS2 tag values are SI / scale).
    pub irradiance_scale_tag: Option<f64>,
    /// Arbitrary units of DJI's `Irradiance` per W/(m^2 nm).
    pub dji_irradiance_units: f64,
}

/// One band of a profile's table (the fields a camera model sets; the rest keep their defaults).
#[derive(Debug, Clone, Copy, Default)]
struct Row {
    name: &'static str,
    suffix: u32,
    center_nm: f64,
    fwhm_nm: f64,
    /// Focal length relative to the camera's nominal one.
    focal: f64,
    /// Principal-point offset from the image centre, pixels (native size).
    pp: [f64; 2],
    /// Distortion relative to the camera's base coefficients.
    dist: [f64; 5],
    rot: [f64; 3],
    trans: [f64; 3],
    a1: f64,
    sga: f64,
    panel: f64,
}

fn lens(f: f64, cx: f64, cy: f64, d: [f64; 5]) -> Lens {
    Lens { fx: f, fy: f, cx, cy, k1: d[0], k2: d[1], k3: d[2], p1: d[3], p2: d[4] }
}

/// The vignetting polynomial of the real RedEdge Blue band (tests/fixtures/real), the base of the MicaSense profiles.
const MICASENSE_VIGNETTING: [f64; 6] = [
    -3.188_190_987_533_484e-5,
    1.138_074_145_205_65e-7,
    -2.777_682_977_814_242e-9,
    9.981_184_981_301_047e-12,
    -1.470_393_673_857_864e-14,
    7.334_097_230_810_222e-18,
];

impl SensorProfile {
    /// The camera at its native resolution.
    pub fn new(kind: SensorKind) -> SensorProfile {
        match kind {
            SensorKind::MicasenseRededge => {
                micasense(kind, "RedEdge-M", "v6.2.1", 1280, 960, 266.6667, 5.4, Some(0.01))
            }
            SensorKind::MicasenseAltum => micasense(kind, "Altum", "v2.0.0", 2064, 1544, 289.855072, 7.8, None),
            SensorKind::DjiP4m => dji_p4m(),
        }
    }

    /// The same camera with its sensor resampled to `width` x `height` (same field of view): focal lengths,
    /// principal points, vignetting centres and focal-plane resolution scale with the image; the vignetting
    /// polynomial is rescaled to the new pixel radius and the row-gradient coefficients a2, a3 to the new rows (the
    /// same gradient from the top row to the bottom one). For CI-sized flights.
    pub fn scaled(mut self, width: u32, height: u32) -> SensorProfile {
        let (sx, sy) = (width as f64 / self.width as f64, height as f64 / self.height as f64);
        let s = 0.5 * (sx + sy);
        for b in &mut self.bands {
            let l = &mut b.lens;
            l.fx *= s;
            l.fy *= s;
            l.cx = (l.cx + 0.5) * sx - 0.5;
            l.cy = (l.cy + 0.5) * sy - 0.5;
            b.vignetting_center =
                [(b.vignetting_center[0] + 0.5) * sx - 0.5, (b.vignetting_center[1] + 0.5) * sy - 0.5];
            // k_i r^(i+1) with r = r_new / s.
            for (i, k) in b.vignetting_poly.iter_mut().enumerate() {
                *k /= s.powi(i as i32 + 1);
            }
            // R(y) = 1 / (1 + a2 y / t - a3 y) with y = y_new / sy.
            b.radiometric[1] /= sy;
            b.radiometric[2] /= sy;
        }
        self.focal_plane_px_per_mm *= s;
        self.width = width;
        self.height = height;
        self
    }

    /// Full scale of the 16-bit container in DN (12-bit data shifted by 4 tops out at 65520).
    pub fn container_max(&self) -> f64 {
        (((1u32 << self.adc_bits) - 1) << self.adc_shift) as f64
    }
}

#[allow(clippy::too_many_arguments)]
fn micasense(
    kind: SensorKind,
    model: &'static str,
    firmware: &str,
    w: u32,
    h: u32,
    px_per_mm: f64,
    focal_mm: f64,
    scale_tag: Option<f64>,
) -> SensorProfile {
    let (cx, cy) = (w as f64 / 2.0 - 0.5, h as f64 / 2.0 - 0.5);
    let f = focal_mm * px_per_mm;
    // Band widths: MicaSense RedEdge-MX / Altum sheets.
    let base = [-0.0968, 0.1404, -0.0230, 0.000276, 0.000660];
    let row = |name, suffix, center_nm, fwhm_nm| Row { name, suffix, center_nm, fwhm_nm, ..Row::default() };
    let table = [
        Row {
            focal: 1.0020,
            pp: [6.1, -4.2],
            dist: [1.04, 0.97, 1.0, 0.9, 1.1],
            rot: [-0.131, 0.418, 0.057],
            trans: [-0.040, 0.0, 0.0],
            a1: 1.46e-4,
            panel: 0.512,
            ..row("Blue", 1, 475.0, 32.0)
        },
        Row {
            focal: 1.0,
            pp: [0.0, 0.0],
            dist: [1.0; 5],
            rot: [0.0; 3],
            trans: [0.0; 3],
            a1: 1.86e-4,
            panel: 0.513,
            ..row("Green", 2, 560.0, 27.0)
        },
        Row {
            focal: 0.9965,
            pp: [-5.3, 3.8],
            dist: [0.95, 1.05, 1.02, 1.2, 0.8],
            rot: [0.309, -0.224, -0.048],
            trans: [0.020, 0.0, 0.0],
            a1: 2.47e-4,
            panel: 0.511,
            ..row("Red", 3, 668.0, 14.0)
        },
        Row {
            focal: 1.0041,
            pp: [3.7, 7.4],
            dist: [1.08, 0.93, 0.97, 0.7, 1.3],
            rot: [-0.262, -0.351, 0.114],
            trans: [0.0, 0.020, 0.0],
            a1: 3.04e-4,
            panel: 0.505,
            ..row("NIR", 4, 842.0, 57.0)
        },
        Row {
            focal: 0.9987,
            pp: [-2.9, -6.6],
            dist: [0.98, 1.02, 1.01, 1.1, 0.9],
            rot: [0.184, 0.268, -0.083],
            trans: [-0.020, 0.020, 0.0],
            a1: 2.75e-4,
            panel: 0.509,
            ..row("Red edge", 5, 717.0, 12.0)
        },
    ];
    let bands = table
        .iter()
        .enumerate()
        .map(|(i, r)| BandCamera {
            name: r.name,
            suffix: r.suffix,
            center_nm: r.center_nm,
            fwhm_nm: r.fwhm_nm,
            lens: lens(
                f * r.focal,
                cx + r.pp[0] * w as f64 / 1280.0,
                cy + r.pp[1] * w as f64 / 1280.0,
                std::array::from_fn(|k| base[k] * r.dist[k]),
            ),
            rig_rotation_deg: r.rot,
            rig_translation_m: r.trans,
            radiometric: [r.a1, 1.18e-7 * (1.0 + 0.05 * i as f64), 1.40e-6 * (1.0 - 0.04 * i as f64)],
            vignetting_center: [
                cx + (30.0 - 9.0 * i as f64) * w as f64 / 1280.0,
                cy + (6.0 * i as f64 - 12.0) * w as f64 / 1280.0,
            ],
            vignetting_poly: {
                // The real polynomial is in RedEdge pixels (1280 wide); per band 5 % apart in strength.
                let s = 1280.0 / w as f64;
                std::array::from_fn(|k| {
                    MICASENSE_VIGNETTING[k] * (1.0 + 0.05 * (i as f64 - 2.0)) * s.powi(k as i32 + 1)
                })
            },
            gain_adjustment: 1.0,
            panel_reflectance: r.panel,
        })
        .collect();
    SensorProfile {
        kind,
        vendor: Vendor::MicaSense,
        make: "MicaSense",
        model,
        firmware: firmware.to_string(),
        width: w,
        height: h,
        focal_plane_px_per_mm: px_per_mm,
        adc_bits: 12,
        adc_shift: 4,
        black_level: 4800.0,
        read_noise_dn: 1.5,
        electrons_per_dn: 2.4,
        f_number: if kind == SensorKind::MicasenseAltum { 1.8 } else { 2.8 },
        reference: 1,
        bands,
        thermal: (kind == SensorKind::MicasenseAltum).then_some(ThermalBand { suffix: 6, width: 160, height: 120 }),
        irradiance_scale_tag: scale_tag,
        dji_irradiance_units: 0.0,
    }
}

fn dji_p4m() -> SensorProfile {
    let (w, h) = (1600u32, 1300u32);
    let (cx, cy) = (w as f64 / 2.0 - 0.5, h as f64 / 2.0 - 0.5);
    let f = 1850.0;
    let base = [-0.0917, 0.0842, -0.0181, 0.00021, -0.00015];
    // Bands in DJI's file order (DJI_xxx1 .. DJI_xxx5); the NIR camera is the reference of the relative optical
    // centres. The rig offsets are small rotations giving centre offsets of a few pixels.
    let row = |name, suffix, center_nm, fwhm_nm| Row { name, suffix, center_nm, fwhm_nm, ..Row::default() };
    let table = [
        Row { pp: [4.2, -3.1], rot: [0.128, -0.096, 0.021], sga: 1.041, panel: 0.506, ..row("Blue", 1, 450.0, 32.0) },
        Row { pp: [-3.6, 2.7], rot: [-0.085, 0.112, -0.017], sga: 0.992, panel: 0.508, ..row("Green", 2, 560.0, 32.0) },
        Row { pp: [2.8, 5.0], rot: [0.154, 0.073, 0.012], sga: 1.018, panel: 0.507, ..row("Red", 3, 650.0, 32.0) },
        Row {
            pp: [-5.1, -2.2],
            rot: [-0.047, -0.131, -0.024],
            sga: 0.976,
            panel: 0.505,
            ..row("RedEdge", 4, 730.0, 32.0)
        },
        Row { sga: 1.0, panel: 0.501, ..row("NIR", 5, 840.0, 52.0) },
    ];
    let bands = table
        .iter()
        .enumerate()
        .map(|(i, r)| BandCamera {
            name: r.name,
            suffix: r.suffix,
            center_nm: r.center_nm,
            fwhm_nm: r.fwhm_nm,
            lens: lens(
                f * (1.0 + 0.002 * (i as f64 - 2.0)),
                cx + r.pp[0],
                cy + r.pp[1],
                std::array::from_fn(|k| base[k] * (1.0 + 0.04 * (i as f64 - 2.0))),
            ),
            rig_rotation_deg: r.rot,
            rig_translation_m: [0.0; 3],
            radiometric: [1.0, 0.0, 0.0],
            vignetting_center: [cx + 11.0 - 4.0 * i as f64, cy - 7.0 + 3.0 * i as f64],
            // Multiplying polynomial: about 1.35 at the corners.
            vignetting_poly: [0.0, 1.2e-7 * (1.0 + 0.03 * i as f64), 0.0, 1.0e-13, 0.0, 0.0],
            gain_adjustment: r.sga,
            panel_reflectance: r.panel,
        })
        .collect();
    SensorProfile {
        kind: SensorKind::DjiP4m,
        vendor: Vendor::Dji,
        make: "DJI",
        model: "FC6360",
        firmware: "v02.00.0501".into(),
        width: w,
        height: h,
        focal_plane_px_per_mm: 322.58,
        adc_bits: 16,
        adc_shift: 0,
        black_level: 4096.0,
        read_noise_dn: 24.0,
        electrons_per_dn: 0.15,
        f_number: 2.2,
        reference: 4,
        bands,
        thermal: None,
        irradiance_scale_tag: None,
        dji_irradiance_units: 1000.0,
    }
}
