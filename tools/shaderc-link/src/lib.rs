//! Build helper for msnerf's `build.rs` (a build-dependency, nothing to call). Debian 12 ships shaderc split in
//! pieces: `libshaderc_combined.a` holds only shaderc's own objects, glslang and SPIRV-Tools live in their own
//! static archives, and `libshaderc.so.1` is underlinked (it needs glslang symbols but names no library). With
//! shaderc's `prefer-static-linking`, shaderc-sys links Debian's `libshaderc_combined.a`; this crate's build
//! script adds the glslang and SPIRV-Tools archives, so a plain `cargo build` works on a fresh Debian machine
//! with `libshaderc-dev glslang-dev spirv-tools` installed, without a setup step.
