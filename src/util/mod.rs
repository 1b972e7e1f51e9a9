//! Small generic helpers shared across layers.

pub mod atomic;
