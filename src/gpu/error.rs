//! Errors of the GPU runtime. Library code returns these; `anyhow` is used only by the binary, tools and tests.

use ash::vk;

pub type GpuResult<T> = Result<T, GpuError>;

#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("Vulkan loader not found ({0}). Install it: `apt-get install libvulkan1 mesa-vulkan-drivers` (or run tools/setup-debian.sh)")]
    Loader(String),
    #[error("no Vulkan device found{0}. On a machine without a GPU install Mesa lavapipe: `apt-get install mesa-vulkan-drivers libvulkan1` (or run tools/setup-debian.sh)")]
    NoDevice(String),
    #[error("device {requested:?} not found; available: {available}")]
    DeviceNotFound { requested: String, available: String },
    #[error("{op} failed: {res}")]
    Vulkan { op: &'static str, res: vk::Result },
    #[error("allocating {name:?} ({bytes} bytes) failed: {source}")]
    Alloc { name: String, bytes: u64, source: gpu_allocator::AllocationError },
    #[error("the device lacks {0}")]
    MissingCapability(&'static str),
    #[error("validation layer VK_LAYER_KHRONOS_validation is required (MSNERF_REQUIRE_VALIDATION=1) but not installed: `apt-get install vulkan-validationlayers`")]
    ValidationUnavailable,
    #[error("shader {name}: {msg}")]
    Shader { name: String, msg: String },
    #[error("dispatch of {kernel}: {msg}")]
    Dispatch { kernel: String, msg: String },
    #[error("buffer {name:?}: {msg}")]
    Buffer { name: String, msg: String },
    /// A module's configuration is out of range (an MLP or hash-grid shape): `what` names it.
    #[error("{what}: {msg}")]
    Config { what: String, msg: String },
}

/// Maps a `vk::Result` error to [`GpuError::Vulkan`] naming the call.
pub(crate) trait VkCheck<T> {
    fn vk(self, op: &'static str) -> GpuResult<T>;
}

impl<T> VkCheck<T> for Result<T, vk::Result> {
    fn vk(self, op: &'static str) -> GpuResult<T> {
        self.map_err(|res| GpuError::Vulkan { op, res })
    }
}
