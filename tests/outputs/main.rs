//! The outputs test binary: outputs (images, clouds, rasters, metrics), exports, the simulator. One binary per layer, each former test file a module
//! (issue 24: five test binaries to link instead of one per file).

#[path = "../common/mod.rs"]
mod common;
#[path = "../geo_support/mod.rs"]
mod geo_support;
#[path = "../output_support/mod.rs"]
mod output_support;
#[path = "../rig_support/mod.rs"]
mod rig_support;
#[path = "../sim_support/mod.rs"]
mod sim_support;

mod canopy;
mod dsm_fill;
mod export_surface;
mod output_cog;
mod output_compare;
mod output_icp;
mod output_lpips;
mod output_metrics;
mod output_pointcloud;
mod output_raster;
mod photometric_refine;
mod render_views;
mod sim_dataset;
mod sim_effects;
mod sim_geometry;
mod sim_radiometry;
mod sim_raw_rig;
mod sim_truth;
mod survey_units;
mod terrain_smrf;
