//! `Context`: the selected device and everything shared by kernels and buffers: queue, allocator, memory
//! ledger, the one descriptor-set layout and pipeline layout, the pipeline cache, the command pool and the
//! timeline semaphore that tracks submissions.
//!
//! Device selection: `--device <index|name>` or `MSNERF_DEVICE`, else discrete GPU, then integrated, then
//! virtual, then a CPU device (lavapipe) with a logged note. A `Context` is a cheap handle (an `Arc`).

use super::caps::DeviceCaps;
use super::error::{GpuError, GpuResult, VkCheck};
use super::instance::{validation_available, InstanceShared};
use super::kernel::PipelineCache;
use super::memory::{MemoryLedger, MemoryReport};
use super::staging::StagingBuffers;
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex, MutexGuard};

/// Storage-buffer bindings in the one descriptor-set layout every kernel shares (ggml uses 12).
pub const MAX_BINDINGS: u32 = 12;
/// Uniform texel buffer slots after the storage bindings: a kernel declares them at `binding = 12, 13`
/// (`TEXEL_BINDING_BASE`), bound from [`crate::gpu::Binding`]s that carry a view.
pub const TEXEL_BINDING_BASE: u32 = MAX_BINDINGS;
pub const TEXEL_BINDINGS: u32 = 2;
/// Push-constant bytes every pipeline layout reserves: the lavapipe limit and Vulkan's guaranteed minimum.
pub const PUSH_CONSTANT_BYTES: u32 = 128;

#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Validation {
    Off,
    IfAvailable,
    Required,
}

#[derive(Clone, Debug)]
pub struct ContextDesc {
    /// Device index (as `msnerf devices` lists them) or a case-insensitive part of its name.
    pub device: Option<String>,
    pub validation: Validation,
    /// Bind descriptors through pools even when VK_KHR_push_descriptor exists (tests the fallback path;
    /// also `MSNERF_DISABLE_PUSH_DESCRIPTOR=1`).
    pub force_descriptor_pools: bool,
    /// Fill every new device buffer with quiet-NaN bits (0x7FC00000) before first use, so a kernel that reads memory
    /// nobody wrote gets NaN (or a huge index) instead of the zeros lavapipe tends to hand out; `make test` sets it
    /// (`MSNERF_POISON_BUFFERS=1`). NVIDIA memory is not zeroed either, so such a read is a real bug there.
    pub poison_buffers: bool,
}

impl ContextDesc {
    /// From the environment: `MSNERF_DEVICE`, and `MSNERF_REQUIRE_VALIDATION=1` / `MSNERF_VALIDATION=1`.
    pub fn from_env() -> Self {
        let env = crate::util::env::settings();
        let validation = if env.require_validation {
            Validation::Required
        } else if env.validation {
            Validation::IfAvailable
        } else {
            Validation::Off
        };
        Self {
            device: env.device.clone(),
            validation,
            force_descriptor_pools: env.disable_push_descriptor,
            poison_buffers: env.poison_buffers,
        }
    }
}

pub(crate) struct DeviceShared {
    pub device: ash::Device,
    pub queue: Mutex<vk::Queue>,
    pub caps: DeviceCaps,
    pub allocator: ManuallyDrop<Mutex<Allocator>>,
    pub ledger: Mutex<MemoryLedger>,
    pub push_descriptor: Option<ash::khr::push_descriptor::Device>,
    pub debug_utils: Option<ash::ext::debug_utils::Device>,
    pub set_layout: vk::DescriptorSetLayout,
    pub pipeline_layout: vk::PipelineLayout,
    pub pipelines: Mutex<PipelineCache>,
    /// Command pools not in use, each with its one command buffer (reset). A recorder takes one for itself: a
    /// pool may be used by one thread at a time (Vulkan's external synchronisation), and tests and the trainer
    /// record from several threads on one context.
    pub idle_pools: Mutex<Vec<(vk::CommandPool, vk::CommandBuffer)>>,
    pub queue_family: u32,
    /// Pools whose submission failed or was never waited for: destroyed with the device, after it idles.
    pub lost_pools: Mutex<Vec<vk::CommandPool>>,
    pub timeline: vk::Semaphore,
    /// Last value signalled on the timeline (guarded with the queue).
    pub timeline_value: Mutex<u64>,
    pub staging: Mutex<StagingBuffers>,
    pub host_clock: super::host_clock::HostClock,
    /// [`ContextDesc::poison_buffers`].
    pub poison_buffers: bool,
    // Declared last: dropped after the device (see Drop).
    pub instance: ManuallyDrop<InstanceShared>,
}

/// The GPU context. Clone it freely: clones share one device.
#[derive(Clone)]
pub struct Context {
    pub(crate) shared: Arc<DeviceShared>,
}

fn rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

/// A physical device with a compute queue family, in the order `msnerf devices` lists them.
pub(crate) struct Candidate {
    pub pdev: vk::PhysicalDevice,
    pub queue_family: u32,
    pub caps: DeviceCaps,
}

pub(crate) fn candidates(
    entry: &ash::Entry,
    instance: &ash::Instance,
    with_coopmat: bool,
) -> GpuResult<Vec<Candidate>> {
    let pdevs = unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
    let mut out = Vec::new();
    for pdev in pdevs {
        let fams = unsafe { instance.get_physical_device_queue_family_properties(pdev) };
        // Prefer a compute-only family (async compute), else any family with compute.
        let qf = fams
            .iter()
            .position(|f| {
                f.queue_flags.contains(vk::QueueFlags::COMPUTE) && !f.queue_flags.contains(vk::QueueFlags::GRAPHICS)
            })
            .or_else(|| fams.iter().position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE)));
        if let Some(qf) = qf {
            let caps = DeviceCaps::query(entry, instance, pdev, Some(qf as u32), with_coopmat);
            out.push(Candidate { pdev, queue_family: qf as u32, caps });
        }
    }
    Ok(out)
}

/// Every Vulkan device with a compute queue, with its caps (no logical device is created).
pub fn list_devices() -> GpuResult<Vec<DeviceCaps>> {
    let inst = InstanceShared::new(false)?;
    Ok(candidates(&inst.entry, &inst.raw, true)?.into_iter().map(|c| c.caps).collect())
}

fn select(cands: &[Candidate], requested: Option<&str>) -> GpuResult<usize> {
    let caps: Vec<DeviceCaps> = cands.iter().map(|c| c.caps.clone()).collect();
    default_device_index(&caps, requested)
}

/// The device a context would use: the one `requested` names (index or part of the name), else the
/// best-ranked type (discrete, integrated, virtual, CPU).
pub fn default_device_index(cands: &[DeviceCaps], requested: Option<&str>) -> GpuResult<usize> {
    if cands.is_empty() {
        return Err(GpuError::NoDevice(String::new()));
    }
    if let Some(req) = requested {
        let by_index = req.parse::<usize>().ok().filter(|&i| i < cands.len());
        let by_name = || cands.iter().position(|c| c.name.to_lowercase().contains(&req.to_lowercase()));
        return by_index.or_else(by_name).ok_or_else(|| GpuError::DeviceNotFound {
            requested: req.to_owned(),
            available: cands.iter().enumerate().map(|(i, c)| format!("{i}: {}", c.name)).collect::<Vec<_>>().join(", "),
        });
    }
    let best = (0..cands.len()).min_by_key(|&i| {
        let t = match cands[i].device_type.as_str() {
            "DISCRETE_GPU" => vk::PhysicalDeviceType::DISCRETE_GPU,
            "INTEGRATED_GPU" => vk::PhysicalDeviceType::INTEGRATED_GPU,
            "VIRTUAL_GPU" => vk::PhysicalDeviceType::VIRTUAL_GPU,
            "CPU" => vk::PhysicalDeviceType::CPU,
            _ => vk::PhysicalDeviceType::OTHER,
        };
        (rank(t), i)
    });
    Ok(best.expect("candidates is not empty"))
}

impl Context {
    pub fn new(desc: &ContextDesc) -> GpuResult<Self> {
        let entry = super::instance::load_entry()?;
        let validation = match desc.validation {
            Validation::Off => false,
            Validation::IfAvailable => validation_available(&entry),
            Validation::Required => {
                if !validation_available(&entry) {
                    return Err(GpuError::ValidationUnavailable);
                }
                true
            }
        };
        // VK_KHR_cooperative_matrix came with Vulkan 1.3.255: an older layer (Debian 12 ships 1.3.239) may report its
        // structures and SPIR-V as errors, so under such a layer it is not even queried and its kernels stay off.
        let layer_knows_coopmat = !validation
            || super::instance::validation_layer_version(&entry)
                .is_some_and(|v| v >= vk::make_api_version(0, 1, 3, 255));
        drop(entry);
        let instance = InstanceShared::new(validation)?;
        let cands = candidates(&instance.entry, &instance.raw, layer_knows_coopmat)?;
        let chosen = select(&cands, desc.device.as_deref())?;
        let Candidate { pdev, queue_family, mut caps } = cands.into_iter().nth(chosen).expect("index from select");
        if desc.force_descriptor_pools {
            caps.push_descriptor = false;
        }
        if !layer_knows_coopmat {
            log::info!(
                "cooperative matrices not used: the validation layer predates VK_KHR_cooperative_matrix (1.3.255)"
            );
        }
        if caps.is_cpu {
            log::warn!("using CPU Vulkan device {} (no GPU found or selected): expect it to be slow", caps.name);
        }
        log::info!("device: {}", caps.summary_line());
        let switches = crate::util::env::settings().set_switches();
        if !switches.is_empty() {
            log::info!("environment: {}", switches.join(" "));
        }
        if desc.poison_buffers {
            log::info!("new device buffers are filled with NaN bits before use (MSNERF_POISON_BUFFERS)");
        }
        if !caps.synchronization2 || !caps.timeline_semaphore {
            return Err(GpuError::MissingCapability("Vulkan 1.3 synchronization2 and timeline semaphores"));
        }

        let mut exts = Vec::new();
        if caps.push_descriptor {
            exts.push(ash::khr::push_descriptor::NAME.as_ptr());
        }
        let atomic_ext = caps.float32_atomic_add || caps.shared_float32_atomic_add;
        if atomic_ext {
            exts.push(ash::ext::shader_atomic_float::NAME.as_ptr());
        }
        if caps.cooperative_matrix {
            exts.push(ash::khr::cooperative_matrix::NAME.as_ptr());
        }
        let core = vk::PhysicalDeviceFeatures::default().shader_int64(caps.shader_int64);
        let mut v11 =
            vk::PhysicalDeviceVulkan11Features::default().storage_buffer16_bit_access(caps.storage_buffer_16bit);
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default()
            .timeline_semaphore(true)
            .buffer_device_address(caps.buffer_device_address)
            .shader_float16(caps.shader_float16)
            .vulkan_memory_model(caps.cooperative_matrix)
            .scalar_block_layout(true);
        let mut v13 = vk::PhysicalDeviceVulkan13Features::default()
            .synchronization2(true)
            .subgroup_size_control(caps.subgroup_size_control);
        let mut atomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
            .shader_buffer_float32_atomic_add(caps.float32_atomic_add)
            .shader_shared_float32_atomic_add(caps.shared_float32_atomic_add);
        let prio = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&prio)];
        let mut info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_extension_names(&exts)
            .enabled_features(&core)
            .push_next(&mut v11)
            .push_next(&mut v12)
            .push_next(&mut v13);
        if atomic_ext {
            info = info.push_next(&mut atomic);
        }
        let mut coop = vk::PhysicalDeviceCooperativeMatrixFeaturesKHR::default().cooperative_matrix(true);
        if caps.cooperative_matrix {
            info = info.push_next(&mut coop);
        }
        let device = unsafe { instance.raw.create_device(pdev, &info, None) }.vk("vkCreateDevice")?;
        let queue = unsafe { device.get_device_queue(queue_family, 0) };

        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.raw.clone(),
            device: device.clone(),
            physical_device: pdev,
            debug_settings: Default::default(),
            buffer_device_address: caps.buffer_device_address,
            allocation_sizes: Default::default(),
        })
        .map_err(|e| GpuError::Alloc { name: "allocator".into(), bytes: 0, source: e })?;

        let bindings: Vec<_> = (0..MAX_BINDINGS + TEXEL_BINDINGS)
            .map(|i| {
                let ty = if i < TEXEL_BINDING_BASE {
                    vk::DescriptorType::STORAGE_BUFFER
                } else {
                    vk::DescriptorType::UNIFORM_TEXEL_BUFFER
                };
                vk::DescriptorSetLayoutBinding::default()
                    .binding(i)
                    .descriptor_type(ty)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let flags = if caps.push_descriptor {
            vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR
        } else {
            vk::DescriptorSetLayoutCreateFlags::empty()
        };
        let set_layout = unsafe {
            device.create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default().flags(flags).bindings(&bindings),
                None,
            )
        }
        .vk("vkCreateDescriptorSetLayout")?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(PUSH_CONSTANT_BYTES.min(caps.max_push_constants_size))];
        let layouts = [set_layout];
        let pipeline_layout = unsafe {
            device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default().set_layouts(&layouts).push_constant_ranges(&ranges),
                None,
            )
        }
        .vk("vkCreatePipelineLayout")?;
        let mut sem_type =
            vk::SemaphoreTypeCreateInfo::default().semaphore_type(vk::SemaphoreType::TIMELINE).initial_value(0);
        let timeline =
            unsafe { device.create_semaphore(&vk::SemaphoreCreateInfo::default().push_next(&mut sem_type), None) }
                .vk("vkCreateSemaphore")?;
        let push_descriptor =
            caps.push_descriptor.then(|| ash::khr::push_descriptor::Device::new(&instance.raw, &device));
        let debug_utils = instance.debug_utils.then(|| ash::ext::debug_utils::Device::new(&instance.raw, &device));

        Ok(Self {
            shared: Arc::new(DeviceShared {
                device,
                queue: Mutex::new(queue),
                caps,
                allocator: ManuallyDrop::new(Mutex::new(allocator)),
                ledger: Mutex::new(MemoryLedger::default()),
                push_descriptor,
                debug_utils,
                set_layout,
                pipeline_layout,
                pipelines: Mutex::new(PipelineCache::default()),
                idle_pools: Mutex::new(Vec::new()),
                queue_family,
                lost_pools: Mutex::new(Vec::new()),
                timeline,
                timeline_value: Mutex::new(0),
                staging: Mutex::new(StagingBuffers::default()),
                host_clock: Default::default(),
                poison_buffers: desc.poison_buffers,
                instance: ManuallyDrop::new(instance),
            }),
        })
    }

    pub fn caps(&self) -> &DeviceCaps {
        &self.shared.caps
    }

    pub fn device(&self) -> &ash::Device {
        &self.shared.device
    }

    pub fn validation_enabled(&self) -> bool {
        self.shared.instance.validation_enabled
    }

    /// Validation messages recorded so far (warnings and errors from the layer and the loader).
    pub fn validation_messages(&self) -> Vec<String> {
        lock(&self.shared.instance.messages).clone()
    }

    /// Number of pipelines built so far (each (variant, specialisation) once).
    pub fn pipeline_count(&self) -> usize {
        lock(&self.shared.pipelines).len()
    }

    pub fn memory_report(&self) -> MemoryReport {
        lock(&self.shared.ledger).report()
    }

    /// Runs `f` on the ledger (read peaks, reset them).
    pub fn with_ledger<R>(&self, f: impl FnOnce(&mut MemoryLedger) -> R) -> R {
        f(&mut lock(&self.shared.ledger))
    }

    /// Bytes the device reserves for a storage buffer of `size` bytes, asked without creating it
    /// (`vkGetDeviceBufferMemoryRequirements`): what the ledger will record for such a buffer.
    pub fn buffer_footprint(&self, size: u64) -> u64 {
        let info = vk::BufferCreateInfo::default()
            .size(size.max(super::buffer::MIN_BUFFER_BYTES))
            .usage(self.shared.buffer_usage());
        let q = vk::DeviceBufferMemoryRequirements::default().create_info(&info);
        let mut req = vk::MemoryRequirements2::default();
        unsafe { self.shared.device.get_device_buffer_memory_requirements(&q, &mut req) };
        req.memory_requirements.size
    }

    /// A command pool of this recorder's own with its primary command buffer, begun (from the idle list, or new).
    pub(crate) fn alloc_command_buffer(&self) -> GpuResult<(vk::CommandPool, vk::CommandBuffer)> {
        let d = &self.shared.device;
        let idle = lock(&self.shared.idle_pools).pop();
        let (pool, cmd) = match idle {
            Some(pc) => pc,
            None => {
                let info = vk::CommandPoolCreateInfo::default()
                    .queue_family_index(self.shared.queue_family)
                    .flags(vk::CommandPoolCreateFlags::TRANSIENT);
                let pool = unsafe { d.create_command_pool(&info, None) }.vk("vkCreateCommandPool")?;
                let info = vk::CommandBufferAllocateInfo::default()
                    .command_pool(pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1);
                match unsafe { d.allocate_command_buffers(&info) }.vk("vkAllocateCommandBuffers") {
                    Ok(c) => (pool, c[0]),
                    Err(e) => {
                        unsafe { d.destroy_command_pool(pool, None) };
                        return Err(e);
                    }
                }
            }
        };
        let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        if let Err(e) = unsafe { d.begin_command_buffer(cmd, &begin) }.vk("vkBeginCommandBuffer") {
            unsafe { d.destroy_command_pool(pool, None) };
            return Err(e);
        }
        Ok((pool, cmd))
    }

    /// Resets `pool` (its command buffer back to the initial state) and returns it to the idle list. Only once the
    /// device is done with the command buffer.
    pub(crate) fn free_command_buffer(&self, (pool, cmd): (vk::CommandPool, vk::CommandBuffer)) {
        let d = &self.shared.device;
        match unsafe { d.reset_command_pool(pool, vk::CommandPoolResetFlags::empty()) } {
            Ok(()) => lock(&self.shared.idle_pools).push((pool, cmd)),
            Err(_) => unsafe { d.destroy_command_pool(pool, None) },
        }
    }

    /// Ends `cmd`, submits it, and returns the timeline value that signals its completion.
    pub(crate) fn submit(&self, cmd: vk::CommandBuffer) -> GpuResult<u64> {
        let d = &self.shared.device;
        unsafe { d.end_command_buffer(cmd) }.vk("vkEndCommandBuffer")?;
        let queue = lock(&self.shared.queue);
        let mut value = lock(&self.shared.timeline_value);
        let next = *value + 1;
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
        let signals = [vk::SemaphoreSubmitInfo::default()
            .semaphore(self.shared.timeline)
            .value(next)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let submit = vk::SubmitInfo2::default().command_buffer_infos(&cmds).signal_semaphore_infos(&signals);
        unsafe { d.queue_submit2(*queue, &[submit], vk::Fence::null()) }.vk("vkQueueSubmit2")?;
        self.shared.host_clock.count_submit();
        *value = next;
        Ok(next)
    }

    /// Blocks until the submission with timeline value `ticket` has completed.
    pub(crate) fn wait(&self, ticket: u64) -> GpuResult<()> {
        let sems = [self.shared.timeline];
        let values = [ticket];
        let info = vk::SemaphoreWaitInfo::default().semaphores(&sems).values(&values);
        self.shared.host_clock.count_wait();
        unsafe { self.shared.device.wait_semaphores(&info, u64::MAX) }.vk("vkWaitSemaphores")
    }

    /// The timeline value of the latest completed submission (never blocks).
    pub(crate) fn completed_value(&self) -> GpuResult<u64> {
        unsafe { self.shared.device.get_semaphore_counter_value(self.shared.timeline) }.vk("vkGetSemaphoreCounterValue")
    }

    /// The host-time totals so far ([`super::host_clock`]).
    pub fn host_times(&self) -> super::HostTimes {
        self.shared.host_clock.snapshot()
    }

    pub(crate) fn add_host_time(&self, work: super::host_clock::HostWork, since: std::time::Instant) {
        self.shared.host_clock.add(work, since.elapsed());
    }

    /// Records `f` into a one-time command buffer, submits it and waits (uploads, readbacks).
    pub(crate) fn one_shot(&self, f: impl FnOnce(&ash::Device, vk::CommandBuffer)) -> GpuResult<()> {
        let pc = self.alloc_command_buffer()?;
        f(&self.shared.device, pc.1);
        let result = self.submit(pc.1).and_then(|t| self.wait(t));
        if result.is_ok() {
            self.free_command_buffer(pc);
        } else {
            // Possibly still in use by the device: leave the pool for the device's destruction (after its idle).
            lock(&self.shared.lost_pools).push(pc.0);
        }
        result
    }

    /// Gives `handle` a debug name that validation messages and capture tools show.
    pub(crate) fn name_object<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.shared.debug_utils {
            if let Ok(c) = std::ffi::CString::new(name) {
                let info = vk::DebugUtilsObjectNameInfoEXT::default().object_handle(handle).object_name(&c);
                let _ = unsafe { du.set_debug_utils_object_name(&info) };
            }
        }
    }
}

impl DeviceShared {
    pub fn buffer_usage(&self) -> vk::BufferUsageFlags {
        let mut u = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST;
        if self.caps.buffer_device_address {
            u |= vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        }
        u
    }
}

/// Locks a mutex; a poisoned lock (a panic elsewhere while holding it) still yields the data.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Drop for DeviceShared {
    fn drop(&mut self) {
        // SAFETY: every buffer holds an Arc to this struct, so none is alive here; the device is idled first.
        unsafe {
            let d = &self.device;
            let _ = d.device_wait_idle();
            lock(&self.staging).release(&mut lock(&self.allocator), &mut lock(&self.ledger), d);
            lock(&self.pipelines).destroy(d);
            d.destroy_semaphore(self.timeline, None);
            for (pool, _) in lock(&self.idle_pools).drain(..) {
                d.destroy_command_pool(pool, None);
            }
            for pool in lock(&self.lost_pools).drain(..) {
                d.destroy_command_pool(pool, None);
            }
            d.destroy_pipeline_layout(self.pipeline_layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
            ManuallyDrop::drop(&mut self.allocator);
            d.destroy_device(None);
            ManuallyDrop::drop(&mut self.instance);
        }
    }
}
