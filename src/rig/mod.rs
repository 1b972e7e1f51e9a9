//! Import layer: raw multispectral rig captures (MicaSense, DJI P4M/M3M, Pix4D-XMP rigs) to a calibrated,
//! registered msnerf dataset (`msnerf import rig`). docs/radiometry.md gives the chain and its sources.
//!
//! - [`meta`]: EXIF/TIFF tags and XMP of one file; [`calib`]: vendor conventions -> [`calib::BandFile`];
//! - [`capture`]: grouping files into captures by XMP capture id, bands by wavelength;
//! - [`radiometry`]: raw DN -> radiance; [`panel`], [`calibrate`]: panel detection, irradiance; [`dls`]: DLS2 and
//!   DLS1 (sun angle) irradiance; [`panels`]: panel captures found among a flight's;
//! - [`lens`], [`register`], [`warp`]: undistortion and band-to-band registration (one resampling per band);
//! - [`plane`]: the f32 image type; [`geo`]: GPS -> local ENU pose priors;
//! - [`rig_model`]: `--rig-cameras`, every band kept in its own camera and the rig's geometry written from the XMP;
//! - [`register_dataset`]: `msnerf dataset register`, the same alignment on a dataset already in msnerf's format;
//! - [`flight_checks`]: flight-level checks (reflectance plausibility, registration, GPS) named as warnings;
//! - [`frame`]: one capture through the chain; [`import`]: the whole flow, writing the dataset atomically.

pub mod calib;
pub mod calibrate;
pub mod capture;
pub mod dls;
pub mod error;
pub mod flight_checks;
pub mod frame;
pub mod geo;
pub mod ground_control;
pub mod import;
pub mod lens;
pub mod meta;
pub mod panel;
pub mod panels;
pub mod plane;
pub mod radiometry;
pub mod register;
pub mod register_dataset;
pub mod rig_model;
pub mod warp;

pub use error::RigError;
pub use import::{import_rig, ImportOptions, ImportSummary, IrradianceSource, Registration, Units};
