//! Coordinate reference systems (issue 20): what `transforms.json`'s `crs` key holds ([`Crs`]), and projecting
//! GPS (WGS84) or ECEF positions into a projected CRS ([`Projector`]), and ground control points in OpenDroneMap's
//! `gcp_list.txt` ([`gcp`]).
//!
//! Crates, and why: `crs-definitions` (the EPSG table as PROJ.4 strings and OGC WKT1, no_std static data, the
//! table `proj4rs`' own authors point to) gives every EPSG code a WKT for LAS and a PROJ.4 definition; `proj4rs`
//! (a pure-Rust port of proj4js by 3Liz, the QGIS-server company) does the projection maths, so a bare Debian needs
//! no libproj and the same numbers come out on every machine. Its Transverse Mercator agrees with GDAL/PROJ's
//! `gdaltransform` to 1e-6 m (tests/data/geo_crs.rs).

pub mod crs;
pub mod error;
pub mod gcp;
pub mod project;

pub use crs::{utm_epsg, Crs, CrsKind};
pub use error::{CrsError, GcpError};
pub use project::Projector;
