//! Small generic helpers shared across layers.

pub mod atomic;
pub mod env;
pub mod mem;
pub mod staging;
pub mod stats;
pub mod tiff;
pub mod yaml;
