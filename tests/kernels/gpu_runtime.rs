//! The runtime itself: device caps, the kernel checks, the pipeline cache, the memory ledger, barrier
//! insertion, the descriptor-pool fallback, the per-dispatch timestamp breakdown and NaN-poisoned fresh buffers.

use crate::common;
use common::gpu;
use msnerf::gpu::spirv::{PushMember, Scalar, ScalarKind, SpecConstant};
use msnerf::gpu::{BufferDesc, GpuBuffer, GpuError, Kernel, MemoryCategory};
use msnerf::{ops, shaders};

msnerf::push_constants! {
    /// `fill_u32`'s block (glsl/util/fill.comp).
    struct FillPush { n: u32, offset: u32, value: u32 }
    /// `copy_u32`'s block.
    struct CopyPush { n: u32, src_offset: u32, dst_offset: u32 }
    /// 4 bytes against fill's 12.
    struct ShortPush { n: u32 }
    /// Fill's members with `offset` and `value` swapped: the same size and types, so only the names tell.
    struct SwappedFillPush { n: u32, value: u32, offset: u32 }
    /// Fill's members with `value` a float: the same names, offsets and sizes, only the type tells.
    struct FloatFillPush { n: u32, offset: u32, value: f32 }
}

/// `fill_u32`'s one specialisation constant, set as `ops::fill` sets it for an unaligned range.
const FILL_SPEC: &[(&str, u32)] = &[("VEC", 1)];

/// NVIDIA's driver could be loaded about 33 times in one process (each load takes static TLS that glibc never gives
/// back), and the loader loads it for every instance when no other instance is alive: the 34th context opened one
/// after another found no driver (an H100, 2026-11-26). The process now pins the drivers; 48 contexts in a row,
/// each with a dispatch, must all work.
#[test]
fn contexts_opened_one_after_another_keep_finding_the_driver() {
    for i in 0..48 {
        let g = gpu();
        let buf = GpuBuffer::from_slice(&g, "pin check", MemoryCategory::Other, &[0u32; 64]).expect("buffer");
        let mut rec = g.recorder("pin check").expect("recorder");
        ops::fill(&mut rec, &buf, i, 0, 64).expect("fill");
        rec.submit_and_wait().unwrap_or_else(|e| panic!("context {i}: {e}"));
        assert_eq!(g.download(&buf).expect("download"), vec![i; 64], "context {i}");
    }
    assert!(msnerf::gpu::instance::drivers_pinned(), "the drivers are pinned once a context was opened");
    // What the pin is for, seen on any driver: the libraries a context loaded stay mapped after it is gone (the
    // validation layer, loaded per instance, excepted). Without the pin lavapipe's libvulkan_lvp and its LLVM go.
    let g = gpu();
    let during = mapped_libraries();
    drop(g);
    let after = mapped_libraries();
    let gone: Vec<_> = during.difference(&after).filter(|p| !p.contains("VkLayer")).collect();
    assert!(gone.is_empty(), "libraries unloaded with the context: {gone:?}");
}

/// Shared objects mapped into this process (/proc/self/maps).
fn mapped_libraries() -> std::collections::BTreeSet<String> {
    let maps = std::fs::read_to_string("/proc/self/maps").expect("/proc/self/maps");
    maps.lines().filter_map(|l| l.split_whitespace().nth(5)).filter(|p| p.contains(".so")).map(str::to_owned).collect()
}

#[test]
fn caps_are_read_and_sane() {
    let g = gpu();
    let c = g.caps();
    assert!(!c.name.is_empty());
    assert!(c.max_storage_buffer_range >= 1 << 27, "Vulkan guarantees 128 MiB bindings");
    assert!(c.max_shared_memory >= 16 << 10);
    assert!(c.subgroup_size.is_power_of_two());
    assert!(c.max_workgroup_count[0] >= 65535);
    assert!(c.timestamp_period_ns.is_some(), "both target devices have timestamps");
    let line = c.summary_line();
    assert!(line.contains("subgroup") && line.contains(&c.name));
    let listed = msnerf::gpu::context::list_devices().expect("list devices");
    assert!(listed.iter().any(|d| d.name == c.name));
}

#[test]
fn kernel_creation_checks_push_constants_and_caches_pipelines() {
    let g = gpu();
    // Wrong push-constant type: 4 bytes against the shader's 12.
    let err = Kernel::<ShortPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).err().expect("size mismatch refused");
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    assert!(err.to_string().contains("12 bytes"), "{err}");
    let before = g.pipeline_count();
    let k1 = Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).expect("kernel");
    let k2 = Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).expect("kernel");
    assert_eq!(g.pipeline_count(), before + 1, "the second creation is a cache hit");
    assert_eq!(k1.arity(), 1);
    assert_eq!(k2.local_size(), [256, 1, 1]);
}

#[test]
fn push_members_are_compared_by_name_offset_and_type() {
    let g = gpu();
    // Two swapped u32 fields: the size matches, the member names do not. Refused before a pipeline is built (VEC = 3
    // is used nowhere else, so this is the cache-miss path) ...
    let before = g.pipeline_count();
    let err = Kernel::<SwappedFillPush>::with_spec(&g, &shaders::FILL_U32, &[("VEC", 3)]).err().expect("refused");
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("fill_u32") && msg.contains("`offset` at offset 4") && msg.contains("`value` at offset 4"),
        "{msg}"
    );
    assert_eq!(g.pipeline_count(), before, "nothing built for a refused layout");
    // ... and on a cache hit, after the right type built the same pipeline.
    Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).expect("kernel");
    let err = Kernel::<SwappedFillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).err().expect("refused on a hit");
    assert!(err.to_string().contains("`offset` at offset 4"), "{err}");
    // The same names at the same offsets, but a float where the shader has a uint.
    let err = Kernel::<FloatFillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).err().expect("type refused");
    assert!(
        err.to_string().contains("`value` (offset 8) is 4 bytes of u32 in the shader, 4 bytes of f32 in Rust"),
        "{err}"
    );
    // Another kernel's block of the same size and types.
    let err = Kernel::<FillPush>::new(&g, &shaders::COPY_U32).err().expect("copy's block has other names");
    assert!(err.to_string().contains("copy_u32") && err.to_string().contains("`src_offset`"), "{err}");
}

#[test]
fn specialisation_constants_are_set_by_name() {
    let g = gpu();
    let err = Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, &[("VECTOR", 1)]).err().expect("unknown name");
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("fill_u32") && msg.contains("`VECTOR`") && msg.contains("declares VEC"), "{msg}");
    let err = Kernel::<FillPush>::new(&g, &shaders::FILL_U32).err().expect("VEC left unset");
    assert!(err.to_string().contains("`VEC`") && err.to_string().contains("not set"), "{err}");
    let err = Kernel::<CopyPush>::with_spec(&g, &shaders::COPY_U32, FILL_SPEC).err().expect("copy has no constants");
    assert!(err.to_string().contains("declares none"), "{err}");
    // A kernel without constants needs none; the pipeline cache keys on the resolved (SpecId, value) pairs.
    Kernel::<CopyPush>::new(&g, &shaders::COPY_U32).expect("no constants: new");
    let before = g.pipeline_count();
    Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, &[("VEC", 2)]).expect("kernel");
    Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, &[("VEC", 4), ("VEC", 2)]).expect("the last value wins");
    assert_eq!(g.pipeline_count(), before + 1);
}

#[test]
fn reflection_reads_push_members_and_specialisation_constants() {
    let words = ash::util::read_spv(&mut std::io::Cursor::new(shaders::HASHGRID_FWD.spirv)).expect("SPIR-V words");
    let info = msnerf::gpu::spirv::reflect(&words, &[]).expect("reflect");
    let (u32_, u64_, f32_) = (
        Scalar { kind: ScalarKind::Uint, bytes: 4 },
        Scalar { kind: ScalarKind::Uint, bytes: 8 },
        Scalar { kind: ScalarKind::Float, bytes: 4 },
    );
    let m = |name: &str, offset, size, s| PushMember { name: name.into(), offset, size, scalar: Some(s) };
    // glsl/encoding/hashgrid_fwd.comp: uint64_t params; uint shift; uint param_offset; uint n; uint out_stride;
    // uint out_col; float pad_value; float scale; uint res; uint entries; float weight;
    let expected = [
        m("params", 0, 8, u64_),
        m("shift", 8, 4, u32_),
        m("param_offset", 12, 4, u32_),
        m("n", 16, 4, u32_),
        m("out_stride", 20, 4, u32_),
        m("out_col", 24, 4, u32_),
        m("pad_value", 28, 4, f32_),
        m("scale", 32, 4, f32_),
        m("res", 36, 4, u32_),
        m("entries", 40, 4, u32_),
        m("weight", 44, 4, f32_),
    ];
    assert_eq!(info.push_members, expected);
    assert_eq!(info.push_constant_bytes, 48);
    let c = |id, name: &str, default| SpecConstant { id, name: name.into(), default };
    let expected = [c(0, "F", 2), c(1, "HASHED", 1), c(2, "HASH_CHUNKED", 0), c(3, "PAD", 0), c(4, "VEC_OUT", 1)];
    assert_eq!(info.spec_constants, expected);
    assert!(info.texel_bindings.is_empty());
    // Its texel variant reads the level's chunk from the first texel slot, after the same two storage bindings.
    let words = ash::util::read_spv(&mut std::io::Cursor::new(shaders::HASHGRID_FWD_TEXEL.spirv)).expect("SPIR-V");
    let info = msnerf::gpu::spirv::reflect(&words, &[]).expect("reflect");
    assert_eq!((info.bindings, info.texel_bindings), (vec![0, 1], vec![12]));
    // Every kernel's names survive the build (build.rs keeps OpName / OpMemberName).
    for blob in shaders::ALL {
        let words = ash::util::read_spv(&mut std::io::Cursor::new(blob.spirv)).expect("SPIR-V words");
        let info = msnerf::gpu::spirv::reflect(&words, &[]).expect("reflect");
        assert!(!info.push_members.is_empty(), "{}: every kernel has push constants", blob.name);
        for p in &info.push_members {
            assert!(!p.name.is_empty() && p.scalar.is_some(), "{}: {p:?}", blob.name);
        }
        for s in &info.spec_constants {
            assert!(!s.name.is_empty(), "{}: {s:?}", blob.name);
        }
    }
}

#[test]
fn every_shipped_variant_builds_a_pipeline() {
    let g = gpu();
    for blob in shaders::ALL {
        let words = ash::util::read_spv(&mut std::io::Cursor::new(blob.spirv)).expect("SPIR-V words");
        let info = msnerf::gpu::spirv::reflect(&words, &[]).expect("reflect");
        assert!(info.local_size.iter().product::<u32>() > 0, "{}", blob.name);
        assert!(info.shared_bytes <= g.caps().max_shared_memory, "{}", blob.name);
    }
}

#[test]
fn dispatch_asserts_binding_count_and_range() {
    let g = gpu();
    let k = Kernel::<FillPush>::with_spec(&g, &shaders::FILL_U32, FILL_SPEC).expect("kernel");
    let a =
        GpuBuffer::<u32>::new(&g, &BufferDesc { name: "a", len: 64, category: MemoryCategory::Other }).expect("buffer");
    let mut rec = g.recorder("bad").expect("recorder");
    let push = FillPush { n: 64, offset: 0, value: 7 };
    let err =
        rec.dispatch(&k, &[a.binding(), a.binding()], &push, 64).expect_err("two bindings for a one-binding kernel");
    assert!(err.to_string().contains("2 storage and 0 texel bindings given, the kernel declares 1 and 0"), "{err}");
    // A texel view for a kernel without texel slots is refused the same way.
    let view = a.texel_binding(ash::vk::Format::R32_SFLOAT).expect("view").expect("64 texels bind on every device");
    let err = rec.dispatch(&k, &[a.binding(), view], &push, 64).expect_err("a texel binding for a kernel without one");
    assert!(err.to_string().contains("1 storage and 1 texel bindings given, the kernel declares 1 and 0"), "{err}");
    let err = a.slice(3, 9).expect_err("offset 12 bytes is not aligned to 16 on lavapipe");
    assert!(err.to_string().contains("alignment"), "{err}");
    drop(rec);
    // A binding over maxStorageBufferRange is refused before it reaches the driver.
    let max = g.caps().max_storage_buffer_range as usize;
    let big = GpuBuffer::<u8>::new(&g, &BufferDesc { name: "big", len: max + 256, category: MemoryCategory::Other })
        .expect("buffer");
    let k_copy = Kernel::<CopyPush>::new(&g, &shaders::COPY_U32).expect("kernel");
    let mut rec = g.recorder("too big").expect("recorder");
    let push = CopyPush { n: 1, src_offset: 0, dst_offset: 0 };
    let err = rec.dispatch(&k_copy, &[big.binding(), a.binding()], &push, 1).expect_err("over the binding limit");
    assert!(err.to_string().contains("maxStorageBufferRange"), "{err}");
}

#[test]
fn ledger_counts_exact_bytes_through_alloc_free_cycles() {
    let g = gpu();
    let base = g.memory_report().total_current;
    let sizes = [1usize, 1000, 4096, 65_537, 3 << 20];
    let mut expected_peak = base;
    for round in 0..3 {
        let mut live = Vec::new();
        let mut want = base;
        for (i, &n) in sizes.iter().enumerate() {
            let cat = if i % 2 == 0 { MemoryCategory::Parameters } else { MemoryCategory::Activations };
            let b = GpuBuffer::<f32>::new(&g, &BufferDesc { name: "cycle", len: n, category: cat }).expect("buffer");
            want += g.buffer_footprint((n * 4) as u64);
            live.push(b);
            assert_eq!(g.memory_report().total_current, want, "round {round}, after {} buffers", i + 1);
        }
        expected_peak = expected_peak.max(want);
        let params: u64 = [0, 2, 4].iter().map(|&i| g.buffer_footprint((sizes[i] * 4) as u64)).sum();
        g.with_ledger(|l| assert_eq!(l.current(MemoryCategory::Parameters), params));
        live.truncate(2);
        let left = base + g.buffer_footprint(4) + g.buffer_footprint(4000);
        assert_eq!(g.memory_report().total_current, left);
        drop(live);
        assert_eq!(g.memory_report().total_current, base, "everything freed in round {round}");
    }
    assert_eq!(g.memory_report().total_peak, expected_peak);
    g.with_ledger(|l| {
        l.reset_peaks();
        assert_eq!(l.total_peak(), base);
    });
}

#[test]
fn barriers_only_between_dependent_dispatches() {
    let g = gpu();
    let mk = |name| {
        GpuBuffer::<u32>::new(&g, &BufferDesc { name, len: 1000, category: MemoryCategory::Other }).expect("buffer")
    };
    let (a, b, c) = (mk("a"), mk("b"), mk("c"));
    let mut rec = g.recorder("deps").expect("recorder");
    ops::fill(&mut rec, &a, 1u32, 0, 1000).expect("fill a");
    ops::fill(&mut rec, &b, 2u32, 0, 1000).expect("fill b (independent: no barrier)");
    assert_eq!(rec.barrier_count(), 0);
    ops::copy(&mut rec, &a, 0, &c, 0, 500).expect("copy a->c (reads a: barrier)");
    assert_eq!(rec.barrier_count(), 1);
    ops::copy(&mut rec, &b, 0, &c, 500, 500).expect("copy b->c (c written before: barrier)");
    assert_eq!(rec.barrier_count(), 2);
    rec.submit_and_wait().expect("submit");
    let got = g.download(&c).expect("download");
    assert!(got[..500].iter().all(|&v| v == 1) && got[500..].iter().all(|&v| v == 2));
}

#[test]
fn an_independent_group_waits_once_for_earlier_work_and_never_among_its_members() {
    // `Recorder::independent` (a hash grid's levels): the members write disjoint ranges of one buffer and read
    // one input; one barrier before the group (the input was just written), none among the members, and a later
    // reader of their output waits for all of them.
    let g = gpu();
    let mk = |name| {
        GpuBuffer::<u32>::new(&g, &BufferDesc { name, len: 1000, category: MemoryCategory::Other }).expect("buffer")
    };
    let (src, dst, out) = (mk("src"), mk("dst"), mk("out"));
    let mut rec = g.recorder("group").expect("recorder");
    ops::fill(&mut rec, &src, 7u32, 0, 1000).expect("fill src");
    rec.independent(|rec| {
        for part in 0..4 {
            ops::copy(rec, &src, part * 250, &dst, part * 250, 250)?;
        }
        Ok(())
    })
    .expect("group");
    assert_eq!(rec.barrier_count(), 1, "one barrier after the fill, none among the four copies");
    ops::copy(&mut rec, &dst, 0, &out, 0, 1000).expect("read the group's output");
    assert_eq!(rec.barrier_count(), 2, "the reader waits for the group");
    let nested = rec.independent(|rec| rec.independent(|_| Ok(())));
    assert!(nested.is_err_and(|e| e.to_string().contains("do not nest")));
    rec.submit_and_wait().expect("submit");
    assert!(g.download(&out).expect("download").iter().all(|&v| v == 7));
}

#[test]
fn descriptor_pool_fallback_gives_the_same_results() {
    let g = common::gpu_with(|d| d.force_descriptor_pools = true);
    assert!(!g.caps().push_descriptor);
    let data: Vec<u32> = (0..5000).collect();
    let src = GpuBuffer::from_slice(&g, "src", MemoryCategory::Other, &data).expect("upload");
    let dst = GpuBuffer::<u32>::new(&g, &BufferDesc { name: "dst", len: 5000, category: MemoryCategory::Other })
        .expect("buffer");
    let mut rec = g.recorder("pools").expect("recorder");
    // More dispatches than one descriptor pool holds, to cover pool growth.
    for i in 0..300 {
        ops::copy(&mut rec, &src, i, &dst, i, 1).expect("copy");
    }
    ops::copy(&mut rec, &src, 300, &dst, 300, 4700).expect("copy");
    rec.submit_and_wait().expect("submit");
    common::assert_same(&g.download(&dst).expect("download"), &data, "pool fallback copy");
    // Texel buffer views go through the pools too: a hash grid forward reading its tables as texels.
    use msnerf::nn::hashgrid::{HashGrid, HashGridConfig, OutputSlot};
    let cfg = HashGridConfig {
        n_levels: 4,
        features_per_level: 2,
        log2_hashmap_size: 10,
        base_resolution: 4,
        max_resolution: 64,
    };
    let mut grid = HashGrid::new(&g, &cfg).expect("grid");
    grid.set_texel_reads(true);
    grid.set_one_dispatch(false); // the per-level kernels bind the texel views (GPUs: one dispatch up to 2^20 points)
    let host: Vec<f32> = (0..cfg.n_params()).map(|i| ((i * 37 % 101) as f32 - 50.0) / 50.0).collect();
    let params =
        msnerf::gpu::LargeArray::<f32>::new(&g, "params", cfg.n_params(), MemoryCategory::Parameters).expect("params");
    params.upload(&g, 0, &host).expect("upload");
    let pts: Vec<[f32; 3]> =
        (0..97).map(|i| [(i as f32 * 0.37) % 1.0, (i as f32 * 0.61) % 1.0, (i as f32 * 0.13) % 1.0]).collect();
    let flat: Vec<f32> = pts.iter().flatten().copied().collect();
    let pos = GpuBuffer::from_slice(&g, "pos", MemoryCategory::Activations, &flat).expect("pos");
    let w = cfg.n_output();
    let out = grid.output_buffer(&g, pts.len(), w).expect("out");
    let mut rec = g.recorder("pools, texels").expect("recorder");
    let slot = OutputSlot { stride: w, col: 0, pad_to: w, pad_value: 0.0 };
    let slice = msnerf::nn::ParamSlice { array: &params, offset: 0 };
    grid.forward(&mut rec, slice, &pos, pts.len(), &out, slot).expect("forward");
    rec.submit_and_wait().expect("submit");
    let levels = cfg.levels();
    let want: Vec<f32> = pts.iter().flat_map(|p| msnerf::reference::hashgrid::forward(&levels, 2, &host, *p)).collect();
    common::assert_all_close_f32(&g.download(&out).expect("download"), &want, "pool fallback, texel reads");
}

#[test]
fn timestamps_name_every_dispatch() {
    let g = gpu();
    let a = GpuBuffer::<f32>::from_slice(&g, "a", MemoryCategory::Other, &vec![1.0; 100_000]).expect("upload");
    let out = GpuBuffer::<f32>::new(&g, &BufferDesc { name: "out", len: 100_000, category: MemoryCategory::Other })
        .expect("buffer");
    let sum = GpuBuffer::<f32>::new(&g, &BufferDesc { name: "sum", len: 1, category: MemoryCategory::Other })
        .expect("buffer");
    let mut rec = g.recorder("breakdown").expect("recorder");
    ops::fill(&mut rec, &out, 0.0f32, 0, 100_000).expect("fill");
    ops::copy(&mut rec, &a, 0, &out, 0, 100_000).expect("copy");
    ops::reduce_sum(&mut rec, &out, 100_000, &sum).expect("reduce");
    let report = rec.submit_and_wait().expect("submit");
    let names: Vec<&str> = report.dispatches.iter().map(|d| d.name.as_str()).collect();
    // 100000 elements: 391 partials, then 2, then 1.
    assert_eq!(names, ["fill_u32", "copy_u32", "reduce_sum_f32", "reduce_sum_f32", "reduce_sum_f32"]);
    assert!(report.dispatches.iter().all(|d| d.ms >= 0.0 && d.ms.is_finite()));
    assert!(report.gpu_ms > 0.0 && report.wall_ms > 0.0);
    let by = report.by_kernel();
    assert_eq!(by.iter().find(|k| k.name == "reduce_sum_f32").map(|k| k.count), Some(3));
    assert!(report.table().contains("copy_u32"));
    assert_eq!(g.download(&sum).expect("download")[0], 100_000.0);
}

#[test]
fn upload_and_download_through_staging_in_pieces() {
    let g = gpu();
    // 80 MiB: larger than one 64 MiB staging buffer, so both directions go in two pieces.
    let n = 20 << 20;
    let data: Vec<u32> = (0..n as u32).map(|i| i.wrapping_mul(2_654_435_761)).collect();
    let buf = GpuBuffer::from_slice(&g, "big", MemoryCategory::Images, &data).expect("upload");
    common::assert_same(&g.download(&buf).expect("download"), &data, "80 MiB round trip");
    assert_eq!(g.download_range(&buf, 12_345, 12_400).expect("range"), data[12_345..12_400]);
    // Both staging buffers grew to their 64 MiB cap, and the ledger holds exactly their bytes.
    let staging = g.with_ledger(|l| l.current(MemoryCategory::Staging));
    assert_eq!(staging, 2 * g.buffer_footprint(64 << 20), "staging is ledgered");
    assert!(g.upload(&buf, n - 1, &[1, 2]).is_err(), "an upload past the end is refused");
}

#[test]
fn batched_parts_move_several_ranges_in_one_submission() {
    use msnerf::gpu::staging::Part;
    let g = gpu();
    let a = GpuBuffer::<u32>::from_slice(&g, "a", MemoryCategory::Other, &[7; 10]).expect("a");
    let b = GpuBuffer::<f32>::from_slice(&g, "b", MemoryCategory::Other, &[0.5; 5]).expect("b");
    // Different element types, an odd byte count (3 floats), an empty part, offsets inside the buffers.
    let parts = [
        Part::upload(&a, 2, &[1u32, 2, 3, 4, 5]).expect("part a"),
        Part::upload(&b, 1, &[-1.0f32, -2.0, -3.0]).expect("part b"),
        Part::upload(&a, 0, &[] as &[u32]).expect("empty part"),
    ];
    g.upload_parts(&parts).expect("batched upload");
    assert_eq!(g.download(&a).expect("a"), [7, 7, 1, 2, 3, 4, 5, 7, 7, 7]);
    assert_eq!(g.download(&b).expect("b"), [0.5, -1.0, -2.0, -3.0, 0.5]);
    let got = g
        .download_parts(&[
            Part::download(&b, 1, 4).expect("b range"),
            Part::download(&a, 6, 9).expect("a range"),
            Part::download(&a, 3, 3).expect("empty range"),
        ])
        .expect("batched readback");
    assert_eq!(bytemuck::pod_collect_to_vec::<u8, f32>(&got[0]), [-1.0, -2.0, -3.0]);
    assert_eq!(bytemuck::pod_collect_to_vec::<u8, u32>(&got[1]), [5, 7, 7]);
    assert!(got[2].is_empty());
    assert!(Part::upload(&b, 4, &[1.0f32, 2.0]).is_err(), "a part past the end is refused");
    assert!(Part::download(&a, 5, 11).is_err(), "a range past the end is refused");
}

/// `MSNERF_POISON_BUFFERS` (which `make test` sets): a fresh buffer reads back as quiet-NaN bits, so a kernel that
/// reads memory nobody wrote sees NaN, on lavapipe as on NVIDIA; without it nothing is written.
#[test]
fn poisoned_buffers_start_as_nan() {
    let g = common::gpu_with(|d| d.poison_buffers = true);
    let b: GpuBuffer<f32> =
        GpuBuffer::new(&g, &BufferDesc { name: "poisoned", len: 1000, category: MemoryCategory::Rays })
            .expect("buffer");
    let v = g.download(&b).expect("download");
    assert!(v.iter().all(|x| x.is_nan() && x.to_bits() == 0x7FC0_0000), "every element is the quiet NaN");
    let u: GpuBuffer<u32> =
        GpuBuffer::new(&g, &BufferDesc { name: "poisoned u32", len: 7, category: MemoryCategory::Rays }).expect("u32");
    assert_eq!(g.download(&u).expect("download"), vec![0x7FC0_0000; 7]);
}
