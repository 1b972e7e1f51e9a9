//! `msnerf sweep`: what accuracy costs in time. Trains one model per cell of a grid (`configs/sweeps/*.yaml`)
//! under the same budget, scores held-out views per band at fixed wall-clock points, and writes the measurements
//! (CSV, JSON), plots (SVG, PNG) and a markdown report that says which configuration to pick for a time budget.
//!
//! - [`grid`]: the grid file, its cells, and applying a cell's values to a model config.
//! - [`run`]: training and evaluating the cells, resumably (`OUT/cells/<id>/result.json`).
//! - [`result`]: what is measured per cell.
//! - [`pareto`]: Pareto fronts (time or memory against PSNR).
//! - [`table`]: CSV and JSON files.
//! - [`plots`]: the plots.
//! - [`report`]: the markdown report.
//! - [`error`]: [`SweepError`], naming the file, grid key, cell or stage.

pub mod error;
pub mod grid;
pub mod noise;
pub mod pareto;
pub mod plots;
pub mod report;
pub mod result;
pub mod run;
pub mod table;

pub use error::SweepError;
pub use grid::{Cell, CellConfig, Grid};
pub use result::{BandScore, CellResult, KernelShare, TimePoint};
pub use run::{run_sweep, SweepOptions, SweepOutcome};
