//! The sensor in the simulator (`msnerf simulate --raw-rig CAMERA`): a scene's flight written as the camera's
//! card holds it, one raw single-band TIFF per band and capture, with the truth beside it.
//!
//! - [`profile`]: the cameras (MicaSense RedEdge-MX and Altum, DJI P4 Multispectral): bands, lenses, rig,
//!   radiometric constants, file layout;
//! - [`light`]: the sky's spectral irradiance per band, the light sensor's readings, auto-exposure;
//! - [`forward`]: lens and rig rays, radiance -> DN (MicaSense's published model inverted), noise, quantisation;
//! - [`tags`]: EXIF, GPS and XMP as each maker writes them;
//! - [`flight`]: the captures (rendered band by band through each band's own distorted, rotated, offset
//!   camera), the calibration-panel captures, the card's folders and file names;
//! - [`gcp`]: ground control points and OpenDroneMap's `gcp_list.txt` (`--gcp N`);
//! - [`truth`]: what the files should give back: reflectance, poses, the rig, band correspondences;
//! - [`registration_truth`]: an import's band registration measured against those correspondences.
//!
//! Only what the option asks for runs: a scene simulated without `--raw-rig` runs none of this code. Effects the
//! sensor models itself (`vignetting`, `noise`, `misregistration`, `rig_parallax`) are refused in a scene flown
//! with a raw rig, by name, rather than applied twice.

pub mod flight;
pub mod forward;
pub mod gcp;
pub mod light;
pub mod profile;
pub mod registration_truth;
pub mod tags;
pub mod truth;

pub use flight::{simulate_raw_rig, RawRigOptions, RawRigReport};
pub use profile::{SensorKind, SensorProfile};
