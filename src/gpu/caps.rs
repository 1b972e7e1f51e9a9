//! `DeviceCaps`: the limits and features every kernel choice reads, queried once per physical device and
//! logged on one line (ggml-vulkan style). Environment switches turn optional paths off:
//! `MSNERF_DISABLE_F16=1` (no fp16 arithmetic or storage), `MSNERF_DISABLE_PUSH_DESCRIPTOR=1` (descriptor pools).

use ash::vk;
use serde::Serialize;
use std::ffi::CStr;

#[derive(Clone, Debug, Serialize)]
pub struct MemoryHeap {
    pub bytes: u64,
    pub device_local: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct DeviceCaps {
    pub name: String,
    pub device_type: String,
    pub vendor_id: u32,
    pub device_id: u32,
    pub driver_name: String,
    pub driver_info: String,
    pub api_version: String,
    /// Largest range one storage-buffer binding may cover (128 MiB on lavapipe).
    pub max_storage_buffer_range: u64,
    pub max_buffer_size: u64,
    pub max_memory_allocation_size: u64,
    pub min_storage_buffer_offset_alignment: u64,
    /// Shared memory per workgroup (32 KiB on lavapipe, 48 KiB on NVIDIA).
    pub max_shared_memory: u32,
    pub max_workgroup_invocations: u32,
    pub max_workgroup_size: [u32; 3],
    pub max_workgroup_count: [u32; 3],
    pub max_push_constants_size: u32,
    /// Largest uniform texel buffer view, in texels, and the alignment of its offset in bytes.
    pub max_texel_buffer_elements: u32,
    pub min_texel_buffer_offset_alignment: u64,
    pub subgroup_size: u32,
    pub min_subgroup_size: u32,
    pub max_subgroup_size: u32,
    pub subgroup_arithmetic: bool,
    pub subgroup_shuffle: bool,
    pub float32_atomic_add: bool,
    pub shared_float32_atomic_add: bool,
    pub shader_float16: bool,
    pub storage_buffer_16bit: bool,
    pub shader_int64: bool,
    pub buffer_device_address: bool,
    pub push_descriptor: bool,
    pub subgroup_size_control: bool,
    pub timeline_semaphore: bool,
    pub synchronization2: bool,
    /// VK_KHR_cooperative_matrix in compute shaders with 16 x 16 x 16 fp16 products accumulated in fp32 at subgroup
    /// scope, 32-wide subgroups with arithmetic, fp16 arithmetic and the Vulkan memory model: what `mlp_coop_layer`
    /// and `mlp_coop_wgrad` need (the build must also carry them: `shaders::MLP_COOP_LAYER`).
    /// `MSNERF_DISABLE_COOPMAT=1` turns it off.
    pub cooperative_matrix: bool,
    /// Nanoseconds per timestamp tick; `None` when the queue cannot write timestamps.
    pub timestamp_period_ns: Option<f32>,
    pub memory_heaps: Vec<MemoryHeap>,
    pub is_cpu: bool,
}

fn version_string(v: u32) -> String {
    format!("{}.{}.{}", vk::api_version_major(v), vk::api_version_minor(v), vk::api_version_patch(v))
}

fn cstr(bytes: &[std::ffi::c_char]) -> String {
    // SAFETY-free conversion: Vulkan fixed arrays are NUL-terminated within their length.
    let b: Vec<u8> = bytes.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
    String::from_utf8_lossy(&b).into_owned()
}

impl DeviceCaps {
    /// Reads the caps of `pdev`. `queue_family` is the compute queue family (for timestamp support).
    /// `with_coopmat: false` leaves VK_KHR_cooperative_matrix unqueried (a validation layer older than the extension
    /// reports its structures as errors).
    pub fn query(
        entry: &ash::Entry,
        instance: &ash::Instance,
        pdev: vk::PhysicalDevice,
        queue_family: Option<u32>,
        with_coopmat: bool,
    ) -> Self {
        let extensions: Vec<String> = unsafe { instance.enumerate_device_extension_properties(pdev) }
            .unwrap_or_default()
            .iter()
            .map(|e| e.extension_name_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default())
            .collect();
        let has_ext = |name: &CStr| extensions.iter().any(|e| e.as_bytes() == name.to_bytes());
        let has_atomic_float = has_ext(ash::ext::shader_atomic_float::NAME);
        let has_push = has_ext(ash::khr::push_descriptor::NAME);

        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut v11p = vk::PhysicalDeviceVulkan11Properties::default();
        let mut v12p = vk::PhysicalDeviceVulkan12Properties::default();
        let mut v13p = vk::PhysicalDeviceVulkan13Properties::default();
        let has_coop = with_coopmat && has_ext(ash::khr::cooperative_matrix::NAME);
        let mut coop_props = vk::PhysicalDeviceCooperativeMatrixPropertiesKHR::default();
        let mut props2 =
            vk::PhysicalDeviceProperties2::default().push_next(&mut subgroup).push_next(&mut v12p).push_next(&mut v13p);
        if has_coop {
            props2 = props2.push_next(&mut coop_props);
        }
        unsafe { instance.get_physical_device_properties2(pdev, &mut props2) };
        let props = props2.properties;
        let _ = &mut v11p;

        let mut atomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
        let mut v11f = vk::PhysicalDeviceVulkan11Features::default();
        let mut v12f = vk::PhysicalDeviceVulkan12Features::default();
        let mut v13f = vk::PhysicalDeviceVulkan13Features::default();
        let mut feats2 =
            vk::PhysicalDeviceFeatures2::default().push_next(&mut v11f).push_next(&mut v12f).push_next(&mut v13f);
        if has_atomic_float {
            feats2 = feats2.push_next(&mut atomic);
        }
        let mut coop = vk::PhysicalDeviceCooperativeMatrixFeaturesKHR::default();
        if has_coop {
            feats2 = feats2.push_next(&mut coop);
        }
        unsafe { instance.get_physical_device_features2(pdev, &mut feats2) };
        let core = feats2.features;

        let mem = unsafe { instance.get_physical_device_memory_properties(pdev) };
        let memory_heaps = mem.memory_heaps[..mem.memory_heap_count as usize]
            .iter()
            .map(|h| MemoryHeap { bytes: h.size, device_local: h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL) })
            .collect();

        let timestamps = queue_family.is_some_and(|qf| {
            let fams = unsafe { instance.get_physical_device_queue_family_properties(pdev) };
            fams.get(qf as usize).is_some_and(|f| f.timestamp_valid_bits > 0)
        });
        let l = &props.limits;
        let no_f16 = crate::util::env::settings().disable_f16;
        let coop_shape = has_coop
            && coop.cooperative_matrix == vk::TRUE
            && coop_props.cooperative_matrix_supported_stages.contains(vk::ShaderStageFlags::COMPUTE)
            && fp16_subgroup_matrices(&ash::khr::cooperative_matrix::Instance::new(entry, instance), pdev);
        let sg_ops = subgroup.supported_operations;
        DeviceCaps {
            name: cstr(&props.device_name),
            device_type: format!("{:?}", props.device_type),
            vendor_id: props.vendor_id,
            device_id: props.device_id,
            driver_name: cstr(&v12p.driver_name),
            driver_info: cstr(&v12p.driver_info),
            api_version: version_string(props.api_version),
            max_storage_buffer_range: l.max_storage_buffer_range as u64,
            max_buffer_size: v13p.max_buffer_size,
            max_memory_allocation_size: {
                let mut m = vk::PhysicalDeviceMaintenance3Properties::default();
                let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut m);
                unsafe { instance.get_physical_device_properties2(pdev, &mut p2) };
                m.max_memory_allocation_size
            },
            min_storage_buffer_offset_alignment: l.min_storage_buffer_offset_alignment,
            max_shared_memory: l.max_compute_shared_memory_size,
            max_workgroup_invocations: l.max_compute_work_group_invocations,
            max_workgroup_size: l.max_compute_work_group_size,
            max_workgroup_count: l.max_compute_work_group_count,
            max_push_constants_size: l.max_push_constants_size,
            max_texel_buffer_elements: l.max_texel_buffer_elements,
            min_texel_buffer_offset_alignment: l.min_texel_buffer_offset_alignment,
            subgroup_size: subgroup.subgroup_size,
            min_subgroup_size: v13p.min_subgroup_size,
            max_subgroup_size: v13p.max_subgroup_size,
            subgroup_arithmetic: sg_ops.contains(vk::SubgroupFeatureFlags::ARITHMETIC),
            subgroup_shuffle: sg_ops.contains(vk::SubgroupFeatureFlags::SHUFFLE),
            float32_atomic_add: has_atomic_float && atomic.shader_buffer_float32_atomic_add == vk::TRUE,
            shared_float32_atomic_add: has_atomic_float && atomic.shader_shared_float32_atomic_add == vk::TRUE,
            shader_float16: !no_f16 && v12f.shader_float16 == vk::TRUE,
            storage_buffer_16bit: !no_f16 && v11f.storage_buffer16_bit_access == vk::TRUE,
            shader_int64: core.shader_int64 == vk::TRUE,
            buffer_device_address: v12f.buffer_device_address == vk::TRUE,
            push_descriptor: has_push && !crate::util::env::settings().disable_push_descriptor,
            subgroup_size_control: v13f.subgroup_size_control == vk::TRUE,
            timeline_semaphore: v12f.timeline_semaphore == vk::TRUE,
            synchronization2: v13f.synchronization2 == vk::TRUE,
            cooperative_matrix: coop_shape
                && !no_f16
                && !crate::util::env::settings().disable_coopmat
                && v12f.shader_float16 == vk::TRUE
                && v12f.vulkan_memory_model == vk::TRUE
                && subgroup.subgroup_size == 32
                && sg_ops.contains(vk::SubgroupFeatureFlags::ARITHMETIC),
            timestamp_period_ns: (timestamps && l.timestamp_compute_and_graphics == vk::TRUE)
                .then_some(l.timestamp_period),
            memory_heaps,
            is_cpu: props.device_type == vk::PhysicalDeviceType::CPU,
        }
    }

    /// Bytes of the largest device-local heap (the VRAM budget's upper bound).
    pub fn device_local_bytes(&self) -> u64 {
        self.memory_heaps.iter().filter(|h| h.device_local).map(|h| h.bytes).max().unwrap_or(0)
    }

    /// The one-line summary logged at start-up.
    pub fn summary_line(&self) -> String {
        let mib = |b: u64| b / (1 << 20);
        format!(
            "{} ({}, {} {}) | vk {} | heap {} MiB | binding max {} MiB | shared {} KiB | subgroup {} | wg {} | push {} B | f32 atomic add: {} | fp16: {} | bda: {} | push descriptors: {} | coopmat: {} | timestamps: {}",
            self.name,
            self.device_type,
            self.driver_name,
            self.driver_info,
            self.api_version,
            mib(self.device_local_bytes()),
            mib(self.max_storage_buffer_range),
            self.max_shared_memory / 1024,
            self.subgroup_size,
            self.max_workgroup_invocations,
            self.max_push_constants_size,
            yes(self.float32_atomic_add),
            yes(self.shader_float16),
            yes(self.buffer_device_address),
            yes(self.push_descriptor),
            yes(self.cooperative_matrix),
            self.timestamp_period_ns.map(|p| format!("{p} ns/tick")).unwrap_or_else(|| "no".into()),
        )
    }
}

/// Whether the device lists 16 x 16 x 16 subgroup matrices with fp16 A and B and fp32 C and result.
fn fp16_subgroup_matrices(ext: &ash::khr::cooperative_matrix::Instance, pdev: vk::PhysicalDevice) -> bool {
    let props = unsafe { ext.get_physical_device_cooperative_matrix_properties(pdev) }.unwrap_or_default();
    props.iter().any(|p| {
        (p.m_size, p.n_size, p.k_size) == (16, 16, 16)
            && p.a_type == vk::ComponentTypeKHR::FLOAT16
            && p.b_type == vk::ComponentTypeKHR::FLOAT16
            && p.c_type == vk::ComponentTypeKHR::FLOAT32
            && p.result_type == vk::ComponentTypeKHR::FLOAT32
            && p.scope == vk::ScopeKHR::SUBGROUP
    })
}

fn yes(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}
