//! Neural-network building blocks on the GPU runtime: encodings, the optimiser and the parameter store.
//! Each kernel wrapper has a CPU twin in [`crate::reference`].

pub mod adam;
pub mod params;
pub mod sh;
