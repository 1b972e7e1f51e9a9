//! The truth of a raw flight: `truth/flight.json` (the camera as simulated, every capture's pose, GPS error,
//! exposures and irradiance), the card's README, and the band correspondences registration should find
//! ([`band_correspondence`]): where a pixel of the reference band's undistorted camera is seen in another band's
//! raw image, through the scene's geometry (so parallax between the band cameras is included).

use std::path::Path;

use serde_json::json;

use super::flight::RawRigOptions;
use super::forward::{project, RigPose};
use super::profile::{SensorProfile, Vendor};
use crate::sim::render::Prepared;
use crate::sim::writer::write_json;
use crate::sim::{SceneDesc, SimError};

/// A question to [`band_correspondence`]: flight view `view`, the rig's band `reference` whose undistorted pinhole
/// camera `target` = (f, cx, cy) the pixels are in (the importer's target camera), and the band `band` asked about.
#[derive(Debug, Clone, Copy)]
pub struct Correspondence {
    pub view: usize,
    pub reference: usize,
    pub band: usize,
    pub target: (f64, f64, f64),
}

/// Where pixel (x, y) of the question's target camera is seen in the band's raw image (local frame geometry).
pub fn band_correspondence(
    prep: &Prepared,
    profile: &SensorProfile,
    q: &Correspondence,
    x: f64,
    y: f64,
) -> Option<(f64, f64)> {
    let (view, reference, bi, target) = (q.view, q.reference, q.band, q.target);
    let c2w = prep.poses[view];
    let r = RigPose::of(profile, &profile.bands[reference]);
    let (f, cx, cy) = target;
    let d_ref = r.ref_from_band * glam::DVec3::new((x - cx) / f, (y - cy) / f, 1.0);
    let gl = [d_ref.x, -d_ref.y, -d_ref.z];
    let d = [0, 1, 2].map(|i| c2w[i][0] * gl[0] + c2w[i][1] * gl[1] + c2w[i][2] * gl[2]);
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let d = d.map(|c| c / n);
    let oc = [r.center.x, -r.center.y, -r.center.z];
    let o = [0, 1, 2].map(|i| c2w[i][3] + c2w[i][0] * oc[0] + c2w[i][1] * oc[1] + c2w[i][2] * oc[2]);
    let hit = prep.world.trace(o, d);
    let p = [0, 1, 2].map(|i| o[i] + hit.t * d[i]);
    let b = &profile.bands[bi];
    project(&b.lens, &RigPose::of(profile, b), &c2w, p)
}

/// Writes `truth/flight.json`.
#[allow(clippy::too_many_arguments)]
pub fn write_flight_truth(
    truth: &Path,
    profile: &SensorProfile,
    opts: &RawRigOptions,
    desc: &SceneDesc,
    crs: &crate::geo::Crs,
    prep: &Prepared,
    irradiance: &[f64],
    records: &[serde_json::Value],
) -> Result<(), SimError> {
    let bands: Vec<_> = profile
        .bands
        .iter()
        .zip(irradiance)
        .map(|(b, e)| {
            let rig = RigPose::of(profile, b);
            json!({
                "band": b.name, "suffix": b.suffix, "center_nm": b.center_nm, "fwhm_nm": b.fwhm_nm,
                "lens": b.lens, "rig_rotation_deg": b.rig_rotation_deg, "rig_translation_m": b.rig_translation_m,
                "ref_from_band": rig.ref_from_band.to_cols_array(), "center_in_reference_m": rig.center.to_array(),
                "radiometric": b.radiometric, "vignetting_center": b.vignetting_center,
                "vignetting_poly": b.vignetting_poly, "gain_adjustment": b.gain_adjustment,
                "panel_reflectance": b.panel_reflectance, "irradiance_clear_sky": e,
            })
        })
        .collect();
    write_json(
        &truth.join("flight.json"),
        &json!({
            "scene": desc.name,
            "seed": prep.seed,
            "options": {
                "sensor": opts.sensor, "width": profile.width, "height": profile.height, "views": prep.poses.len(),
                "seed": prep.seed, "firmware": profile.firmware, "gps_noise_m": opts.gps_noise_m,
                "gps_shift_m": opts.gps_shift_m, "start": opts.start, "interval_s": opts.interval_s,
            },
            "sensor": profile.kind,
            "make": profile.make,
            "model": profile.model,
            "firmware": profile.firmware,
            "width": profile.width,
            "height": profile.height,
            "reference_band": profile.bands[profile.reference].name,
            "bands": bands,
            "crs": crs.key(),
            "world_offset": prep.world_offset,
            "gps": {
                "noise_m": {"horizontal": opts.gps_noise_m[0], "vertical": opts.gps_noise_m[1]},
                "datum_shift_m": opts.gps_shift_m,
                "note": "written fix = true camera centre + datum_shift_m + noise (east, north, up in the crs); \
                         altitude = ellipsoidal height = world z",
            },
            "radiance_units": match profile.vendor {
                Vendor::MicaSense => "W/(m^2 sr nm)",
                Vendor::Dji => "DJI relative units: radiance times the sun sensor's Irradiance units",
            },
            "captures": records,
        }),
    )
}

/// Writes the flight folder's README.
pub fn write_readme(
    root: &Path,
    p: &SensorProfile,
    opts: &RawRigOptions,
    desc: &SceneDesc,
    n: usize,
) -> Result<(), SimError> {
    let layout = match p.vendor {
        Vendor::MicaSense => "`card/0000SET/NNN/IMG_XXXX_K.tif`: capture XXXX, band suffix K (200 captures a folder)",
        Vendor::Dji => "`card/DJI_001/DJI_XXXK.TIF`: capture XXX, band K",
    };
    let bands: String =
        p.bands.iter().map(|b| format!("| {} | {} | {} | {} |\n", b.suffix, b.name, b.center_nm, b.fwhm_nm)).collect();
    let text = format!(
        "# Raw flight: scene `{scene}` as a {sensor}\n\n\
Written by `msnerf simulate --raw-rig {sensor}`. {n} flight captures of {w}x{h} px; capture 0 is a calibration-panel\n\
capture{after}.\n\n\
- {layout}; one 16-bit single-band TIFF per band with the maker's EXIF, GPS and XMP tags (src/sim/sensor/tags.rs).\n\
- Import it: `msnerf import rig card --out DATA --panel card/{panel} --panel-reflectance` with the values of\n  \
`truth/panel.json`, or with the light sensor alone (`--irradiance dls`); or run `msnerf process card --out PROJECT`.\n\
- GPS: true camera centre + a datum shift of {shift:?} m (east, north, up) + noise of {noise:?} m (horizontal, vertical).\n\
- `truth/flight.json`: the camera as simulated and every capture's true pose, GPS error, exposure and irradiance;\n  \
`truth/panel.json`: the panel's reflectance; `truth/dataset/`: the same flight written directly by the simulator\n  \
(reflectance in the reference band's pinhole camera, depth, ground_truth.ply, truth/dsm.tif and ortho.tif).\n\n\
| suffix | band | centre nm | FWHM nm |\n|---|---|---|---|\n{bands}",
        scene = desc.name,
        sensor = p.kind.name(),
        w = p.width,
        h = p.height,
        after = if opts.panel_after { ", and the last one too" } else { "" },
        panel = super::flight::band_file(p, 0, p.bands[0].suffix),
        shift = opts.gps_shift_m,
        noise = opts.gps_noise_m,
    );
    std::fs::write(root.join("README.md"), text).map_err(SimError::io(root.join("README.md")))
}
