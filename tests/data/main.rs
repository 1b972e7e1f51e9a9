//! The data test binary: datasets, readers, raw rig import, poses from peers, CRS, COLMAP. One binary per layer, each former test file a module
//! (issue 24: five test binaries to link instead of one per file).

#[path = "../common/mod.rs"]
mod common;
#[path = "../data_support/mod.rs"]
mod data_support;
#[path = "../geo_support/mod.rs"]
mod geo_support;
#[path = "../poses_support/mod.rs"]
mod poses_support;
#[path = "../rig_support/mod.rs"]
mod rig_support;

mod data_alpha;
mod data_applied_transform;
mod data_cache;
mod data_errors;
mod data_mutation;
mod data_outliers;
mod data_pose_camera;
mod data_real;
mod data_roundtrip;
mod geo_crs;
mod ground_control;
mod poses_colmap;
mod poses_colmap_rigs;
mod poses_metashape;
mod poses_opensfm;
mod rig_flight;
mod rig_import;
mod rig_real;
mod rig_registration_truth;
mod rig_resample;
mod sfm_bundle;
mod sfm_colmap;
mod sfm_georef;
