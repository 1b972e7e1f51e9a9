//! Compiles every GLSL compute kernel under `glsl/` to SPIR-V with shaderc, from the declarative variant
//! table below, and generates `$OUT_DIR/shaders.rs`: one `ShaderBlob` constant per variant (included by
//! `src/shaders.rs`). Includes resolve against `glsl/` (e.g. `#include "common/index.glsl"`); warnings are
//! errors; every source and include is a `rerun-if-changed` input; a `.comp` file missing from the table
//! is an error, so no kernel is forgotten.
//!
//! shaderc itself: on Debian/Ubuntu, Debian's static `libshaderc_combined.a` (shaderc's `prefer-static-linking`)
//! plus the glslang and SPIRV-Tools archives that `tools/shaderc-link` adds, so `cargo build --release` needs only
//! `apt-get install libshaderc-dev`. Elsewhere: `SHADERC_LIB_DIR` pointing at a complete shaderc, or
//! `--features shaderc-from-source` (builds glslang and SPIRV-Tools; needs cmake and ninja).

// Linked for its build script's side effect: the glslang and SPIRV-Tools archives (see its header).
use msnerf_shaderc_link as _;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One compiled kernel variant: `name` is the Rust constant (upper-cased) and the pipeline-cache key.
struct Variant {
    name: &'static str,
    source: &'static str,
    defines: &'static [(&'static str, &'static str)],
}

const fn v(name: &'static str, source: &'static str) -> Variant {
    Variant { name, source, defines: &[] }
}

const fn vd(name: &'static str, source: &'static str, defines: &'static [(&'static str, &'static str)]) -> Variant {
    Variant { name, source, defines }
}

/// The variant table: every kernel the crate ships.
const VARIANTS: &[Variant] = &[
    // util: generic building blocks (src/ops)
    v("fill_u32", "util/fill.comp"),
    v("copy_u32", "util/copy.comp"),
    vd("reduce_sum_f32", "util/reduce_sum.comp", &[("VALUE_F32", "1")]),
    vd("reduce_sum_u32", "util/reduce_sum.comp", &[("VALUE_U32", "1")]),
    vd("scan_block_f32", "util/scan_block.comp", &[("VALUE_F32", "1")]),
    vd("scan_block_u32", "util/scan_block.comp", &[("VALUE_U32", "1")]),
    vd("scan_add_f32", "util/scan_add.comp", &[("VALUE_F32", "1")]),
    vd("scan_add_u32", "util/scan_add.comp", &[("VALUE_U32", "1")]),
    vd("scan_segmented_f32", "util/scan_segmented.comp", &[("VALUE_F32", "1")]),
    vd("scan_segmented_u32", "util/scan_segmented.comp", &[("VALUE_U32", "1")]),
    v("large_array_iota", "util/large_array_iota.comp"),
    v("copy_cols", "util/copy_cols.comp"),
    v("check_finite", "util/check_finite.comp"),
    // encoding: multiresolution hash grid (src/nn/hashgrid.rs)
    v("hashgrid_fwd", "encoding/hashgrid_fwd.comp"),
    vd("hashgrid_fwd_texel", "encoding/hashgrid_fwd.comp", &[("HASH_TEXEL", "1")]),
    vd("hashgrid_fwd_levels", "encoding/hashgrid_fwd.comp", &[("HASH_LEVELS", "1")]),
    v("hashgrid_bwd", "encoding/hashgrid_bwd.comp"),
    vd("hashgrid_bwd_prefetch", "encoding/hashgrid_bwd.comp", &[("HASH_PREFETCH", "1")]),
    v("hashgrid_bwd_runs", "encoding/hashgrid_bwd_runs.comp"),
    v("hashgrid_bwd_input", "encoding/hashgrid_bwd_input.comp"),
    vd("hashgrid_bwd_input_texel", "encoding/hashgrid_bwd_input.comp", &[("HASH_TEXEL", "1")]),
    vd("hashgrid_bwd_input_levels", "encoding/hashgrid_bwd_input.comp", &[("HASH_LEVELS", "1")]),
    // network: MLP layer, tile and weight-gradient kernels (src/nn/mlp.rs); not fused across layers
    v("mlp_layer_fwd", "network/mlp_layer_fwd.comp"),
    vd("mlp_layer_fwd_texel", "network/mlp_layer_fwd.comp", &[("MLP_TEXEL", "1")]),
    v("mlp_layer_bwd", "network/mlp_layer_bwd.comp"),
    vd("mlp_layer_bwd_texel", "network/mlp_layer_bwd.comp", &[("MLP_TEXEL", "1")]),
    v("mlp_out_delta", "network/mlp_out_delta.comp"),
    v("mlp_wgrad", "network/mlp_wgrad.comp"),
    v("mlp_wgrad_reduce", "network/mlp_wgrad_reduce.comp"),
    v("mlp_tile_layer", "network/mlp_tile_layer.comp"),
    v("mlp_tile_wgrad", "network/mlp_tile_wgrad.comp"),
    // nn: direction encoding and optimiser (src/nn)
    v("sh_fwd", "encoding/sh_fwd.comp"),
    v("sh_bwd", "encoding/sh_bwd.comp"),
    v("adam_step", "optim/adam_step.comp"),
    // render: rays, sampling, compositing and losses (src/nerf)
    v("ray_gen", "render/ray_gen.comp"),
    v("sample_initial", "render/sample_initial.comp"),
    v("sample_initial_edges", "render/sample_initial_edges.comp"),
    v("density_weights", "render/density_weights.comp"),
    v("density_weights_lanes", "render/density_weights_lanes.comp"),
    v("pdf_resample", "render/pdf_resample.comp"),
    v("pdf_resample_lanes", "render/pdf_resample_lanes.comp"),
    v("colour_input", "render/colour_input.comp"),
    v("composite", "render/composite.comp"),
    v("composite_lanes", "render/composite_lanes.comp"),
    v("interlevel", "render/interlevel.comp"),
    v("interlevel_lanes", "render/interlevel_lanes.comp"),
    v("appearance_grad", "render/appearance_grad.comp"),
    // pose: SO3xR3 camera pose refinement (src/nerf/pose.rs)
    v("pose_apply", "pose/pose_apply.comp"),
    v("pose_ray_grad", "pose/pose_ray_grad.comp"),
    v("pose_ray_grad_lanes", "pose/pose_ray_grad_lanes.comp"),
    v("pose_reduce", "pose/pose_reduce.comp"),
    v("pose_regularizer", "pose/pose_regularizer.comp"),
];

/// Kernels that need a glslang newer than Debian 12's (VK_KHR_cooperative_matrix): compiled with the
/// `shaderc-from-source` feature, else generated as `None` (the MLP then runs its fp32 tiles). Not in `ALL`.
const COOP_VARIANTS: &[Variant] =
    &[v("mlp_coop_layer", "network/mlp_coop_layer.comp"), v("mlp_coop_wgrad", "network/mlp_coop_wgrad.comp")];

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let glsl = root.join("glsl");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));

    let mut all_files = Vec::new();
    collect_files(&glsl, &mut all_files);
    for f in &all_files {
        println!("cargo::rerun-if-changed={}", f.display());
    }
    println!("cargo::rerun-if-changed={}", glsl.display());

    // Every kernel source must be in the table.
    for f in all_files.iter().filter(|f| f.extension().is_some_and(|e| e == "comp")) {
        let rel = f.strip_prefix(&glsl).expect("collected under glsl/").to_string_lossy().replace('\\', "/");
        if !VARIANTS.iter().chain(COOP_VARIANTS).any(|v| v.source == rel) {
            panic!("glsl/{rel} is not in build.rs's VARIANTS table: add a row for it");
        }
    }

    // Debian 12's glslang + SPIRV-Tools fold `gl_WorkGroupSize.x` to 1 at -O (see glsl/common/index.glsl).
    for f in all_files.iter().filter(|f| f.extension().is_some_and(|e| e == "comp" || e == "glsl")) {
        let text = std::fs::read_to_string(f).unwrap_or_default();
        if text.lines().any(|l| !l.trim_start().starts_with("//") && l.contains("gl_WorkGroupSize")) {
            panic!("{}: do not read gl_WorkGroupSize (miscompiled by Debian's SPIRV-Tools); use WG_SIZE", f.display());
        }
    }

    let compiler = shaderc::Compiler::new().expect("shaderc compiler could not be created");
    let mut generated = String::from("// @generated by build.rs from the VARIANTS table. Do not edit.\n\n");
    let mut errors = Vec::new();
    // One constant per compiled variant: `ShaderBlob` (`optional`: `Option<ShaderBlob>`, `Some`).
    let mut emit = |var: &Variant, optional: bool, generated: &mut String| match compile(
        &compiler,
        &glsl,
        var.source,
        var.defines,
    ) {
        Ok(words) => {
            let spv = out.join(format!("{}.spv", var.name));
            std::fs::write(&spv, words).expect("write .spv into OUT_DIR");
            let blob = format!(
                "crate::gpu::ShaderBlob {{ name: {:?}, source: {:?}, spirv: include_bytes!({:?}) }}",
                var.name,
                var.source,
                spv.display().to_string(),
            );
            let (ty, value) = if optional {
                ("Option<crate::gpu::ShaderBlob>", format!("Some({blob})"))
            } else {
                ("crate::gpu::ShaderBlob", blob)
            };
            writeln!(generated, "pub const {}: {ty} = {value};", var.name.to_uppercase()).expect("write to String");
        }
        Err(e) => errors.push(format!("{} ({}):\n{}", var.name, var.source, e)),
    };
    for var in VARIANTS {
        emit(var, false, &mut generated);
    }
    let coop = std::env::var_os("CARGO_FEATURE_SHADERC_FROM_SOURCE").is_some();
    writeln!(
        generated,
        "\n/// Cooperative-matrix kernels: `Some` when built with the `shaderc-from-source` feature ({}).",
        if coop { "this build" } else { "not this build" }
    )
    .expect("write to String");
    for var in COOP_VARIANTS {
        if coop {
            emit(var, true, &mut generated);
        } else {
            writeln!(generated, "pub const {}: Option<crate::gpu::ShaderBlob> = None;", var.name.to_uppercase())
                .expect("write to String");
        }
    }
    if !errors.is_empty() {
        panic!("GLSL compilation failed:\n\n{}", errors.join("\n\n"));
    }
    let names: Vec<String> = VARIANTS.iter().map(|v| v.name.to_uppercase()).collect();
    writeln!(
        generated,
        "\n/// Every variant, for tools that enumerate kernels.\npub const ALL: &[&crate::gpu::ShaderBlob] = &[{}];",
        names.iter().map(|n| format!("&{n}")).collect::<Vec<_>>().join(", ")
    )
    .expect("write to String");
    std::fs::write(out.join("shaders.rs"), generated).expect("write shaders.rs");
}

fn collect_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            collect_files(&p, out);
        } else {
            out.push(p);
        }
    }
}

fn compile(
    compiler: &shaderc::Compiler,
    glsl: &Path,
    source: &str,
    defines: &[(&str, &str)],
) -> Result<Vec<u8>, String> {
    let path = glsl.join(source);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let mut opts = shaderc::CompileOptions::new().map_err(|e| format!("shaderc options: {e}"))?;
    opts.set_target_env(shaderc::TargetEnv::Vulkan, shaderc::EnvVersion::Vulkan1_2 as u32);
    opts.set_target_spirv(shaderc::SpirvVersion::V1_5);
    opts.set_source_language(shaderc::SourceLanguage::GLSL);
    opts.set_optimization_level(shaderc::OptimizationLevel::Performance);
    opts.set_warnings_as_errors();
    // Debug info keeps OpName / OpMemberName (shaderc strips all debug instructions when optimising without it):
    // `Kernel::new` compares the push-constant members and specialisation constants with the Rust side by name.
    opts.set_generate_debug_info();
    for (k, v) in defines {
        opts.add_macro_definition(k, Some(v));
    }
    let root = glsl.to_path_buf();
    opts.set_include_callback(move |requested, _ty, requesting, _depth| {
        let from_root = root.join(requested);
        let from_dir = root.join(requesting).parent().map(|d| d.join(requested));
        let found = if from_root.exists() { Some(from_root) } else { from_dir.filter(|p| p.exists()) };
        let found = found.ok_or_else(|| format!("#include \"{requested}\" not found under glsl/"))?;
        let content = std::fs::read_to_string(&found).map_err(|e| format!("{}: {e}", found.display()))?;
        Ok(shaderc::ResolvedInclude {
            resolved_name: found.strip_prefix(&root).unwrap_or(&found).to_string_lossy().into_owned(),
            content,
        })
    });
    let art = compiler
        .compile_into_spirv(&text, shaderc::ShaderKind::Compute, source, "main", Some(&opts))
        .map_err(|e| e.to_string())?;
    if art.get_num_warnings() > 0 {
        return Err(art.get_warning_messages());
    }
    Ok(strip_source_info(art.as_binary()))
}

/// Drops the source-level debug instructions `set_generate_debug_info` adds (OpSource*, OpString, OpLine,
/// OpNoLine, OpModuleProcessed) and keeps the names: the code is the same as without debug info, plus OpName and
/// OpMemberName.
fn strip_source_info(words: &[u32]) -> Vec<u8> {
    const OP_SOURCE_CONTINUED: u32 = 2;
    const OP_SOURCE: u32 = 3;
    const OP_SOURCE_EXTENSION: u32 = 4;
    const OP_STRING: u32 = 7;
    const OP_LINE: u32 = 8;
    const OP_NO_LINE: u32 = 317;
    const OP_MODULE_PROCESSED: u32 = 330;
    let mut out: Vec<u32> = words[..5.min(words.len())].to_vec();
    let mut i = 5;
    while i < words.len() {
        let wc = ((words[i] >> 16) as usize).max(1).min(words.len() - i);
        let op = words[i] & 0xffff;
        let drop = matches!(
            op,
            OP_SOURCE_CONTINUED
                | OP_SOURCE
                | OP_SOURCE_EXTENSION
                | OP_STRING
                | OP_LINE
                | OP_NO_LINE
                | OP_MODULE_PROCESSED
        );
        if !drop {
            out.extend_from_slice(&words[i..i + wc]);
        }
        i += wc;
    }
    out.iter().flat_map(|w| w.to_le_bytes()).collect()
}
