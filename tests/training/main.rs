//! The training test binary: training end to end, the planner, sweeps and benchmarks. One binary per layer, each former test file a module
//! (issue 24: five test binaries to link instead of one per file).

#[path = "../common/mod.rs"]
mod common;
#[path = "../geo_support/mod.rs"]
mod geo_support;

mod background_guard;
mod bench_cli;
mod config_errors;
mod depth_supervision;
mod plan_cli;
mod plan_ledger;
mod process_flight;
mod scale_blocks;
mod sweep_bands;
mod sweep_grid;
mod sweep_outputs;
mod sweep_pareto;
mod sweep_resume;
mod train_coarse_to_fine;
mod train_e2e;
mod train_in_flight;
mod train_pose_refinement;
mod train_rig;
mod train_step;
