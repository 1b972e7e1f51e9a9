//! Small generic helpers shared across layers.

pub mod atomic;
pub mod staging;
pub mod stats;
pub mod tiff;
