//! Benchmarks that print numbers (`msnerf bench ...`). Speed goals are measured here, never in timed tests.

pub mod flight;
pub mod import;
pub mod kernels;
pub mod train;
