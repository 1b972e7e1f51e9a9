//! The stability test binary: numerical stability of hard cases (encodings, networks, rendering, data, the NaN guard). One binary per layer, each former test file a module
//! (issue 24: five test binaries to link instead of one per file).

#[path = "../common/mod.rs"]
mod common;
#[path = "../data_support/mod.rs"]
mod data_support;
#[path = "../stability_support/mod.rs"]
mod stability_support;

mod stability_data;
mod stability_encoding;
mod stability_guard;
mod stability_network;
mod stability_props;
mod stability_render;
