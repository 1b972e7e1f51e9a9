//! Adds Debian's glslang and SPIRV-Tools static archives to the link of whatever build script depends on this
//! crate (msnerf's GLSL compiler), next to the shaderc-only `libshaderc_combined.a` that shaderc-sys picks.
//!
//! The archives are linked whole (`+whole-archive`): rustc orders the native libraries of sibling crates
//! freely, and a whole archive's symbols are defined wherever it lands on the command line. Nothing is added
//! when shaderc is built from source (`from-source`), when `SHADERC_LIB_DIR` points at another shaderc, or on
//! targets other than Linux. A Debian/Ubuntu machine missing a piece gets the apt line to run.

use std::path::Path;

/// glslang (and its split internal archives) then SPIRV-Tools, as Debian 12 / Ubuntu 22.04+ install them.
const ARCHIVES: &[&str] = &[
    "glslang",
    "MachineIndependent",
    "GenericCodeGen",
    "OSDependent",
    "OGLCompiler",
    "HLSL",
    "SPIRV",
    "SPIRV-Tools-opt",
    "SPIRV-Tools",
    "glslang-default-resource-limits",
];

fn main() {
    println!("cargo:rerun-if-env-changed=SHADERC_LIB_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var_os("CARGO_FEATURE_FROM_SOURCE").is_some() || std::env::var_os("SHADERC_LIB_DIR").is_some() {
        return;
    }
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("linux") {
        return;
    }
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    let arch = if arch == "x86" { "i386".to_owned() } else { arch };
    let dir = format!("/usr/lib/{arch}-linux-gnu");
    if !Path::new(&dir).is_dir() {
        // Not a multiarch (Debian-family) system: shaderc-sys finds a complete shaderc on its own, or says how.
        return;
    }
    let combined = Path::new(&dir).join("libshaderc_combined.a");
    let missing: Vec<String> = std::iter::once("shaderc_combined")
        .chain(ARCHIVES.iter().copied())
        .filter(|lib| !Path::new(&dir).join(format!("lib{lib}.a")).is_file())
        .map(|lib| format!("{dir}/lib{lib}.a"))
        .collect();
    if !missing.is_empty() {
        let which = if combined.is_file() { "glslang and SPIRV-Tools" } else { "shaderc" };
        panic!(
            "\n\nmsnerf compiles its GLSL kernels with Debian's static {which} libraries, and these are missing:\n  {}\n\
             Install them with:\n  sudo apt-get install libshaderc-dev glslang-dev spirv-tools\n\
             (or run tools/setup-debian.sh, which installs everything msnerf needs), or build shaderc from source\n\
             with `cargo build --release --features shaderc-from-source` (needs cmake, ninja, python3; ~25 min).\n\n",
            missing.join("\n  ")
        );
    }
    println!("cargo:rustc-link-search=native={dir}");
    for lib in ARCHIVES {
        println!("cargo:rustc-link-lib=static:+whole-archive,-bundle={lib}");
        println!("cargo:rerun-if-changed={dir}/lib{lib}.a");
    }
    println!("cargo:rustc-link-lib=dylib=stdc++");
}
