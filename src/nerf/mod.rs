//! The nerfacto pipeline for B spectral bands: ray generation, proposal sampling, the fields, volume rendering,
//! losses and training (spec/nerfacto.md §2; Multispectral-NeRF §3).

pub mod background_guard;
pub mod buffers;
pub mod camera_path;
pub mod camera_poses;
pub mod config;
pub mod config_error;
pub mod config_extends;
pub mod cross_check;
pub mod depth_targets;
pub mod error;
pub mod evaluate;
pub mod export;
pub mod guard;
pub mod kernels;
pub mod model;
pub mod normals;
pub mod pipeline;
pub mod pose;
pub mod rays;
pub mod refine;
pub mod refine_points;
pub mod registered_eval;
pub mod rig_rays;
pub mod run;
pub mod schedule;
pub mod step_io;
pub mod survey;
pub mod survey_products;
pub mod trainer;
pub mod views;

pub use error::{NerfError, NerfResult};
