//! The Vulkan compute runtime every kernel stands on.
//!
//! - [`Context`]: instance, validation messenger, device selection, queue, allocator, pipeline cache ([`context`]).
//! - [`DeviceCaps`]: the device limits and features read once and logged on one line ([`caps`]).
//! - [`GpuBuffer`] and [`LargeArray`]: named, categorised allocations tracked by the [`MemoryLedger`].
//! - [`Kernel`]: a SPIR-V blob plus its push-constant type, with the dispatch asserts ([`kernel`]); the push
//!   structs are declared with [`push_constants!`](crate::push_constants) and compared member by member with the
//!   shader's block, specialisation constants are set by name ([`push`], [`spirv`]).
//! - [`Recorder`]: records dispatches with automatic barriers and per-dispatch GPU timestamps ([`recorder`]).
//! - [`HostBuffer`]: persistent host-visible buffers a recorded sequence copies from and into ([`host_buffer`]).
//! - [`HostTimes`]: host time spent recording, waiting on submissions and in transfers ([`host_clock`]).
//!
//! Uploads and readbacks go only through staging buffers ([`staging`]): lavapipe can map device memory,
//! NVIDIA cannot, and the API makes no difference between them.

pub mod buffer;
pub mod caps;
pub mod context;
pub mod error;
pub mod host_buffer;
pub mod host_clock;
pub mod instance;
pub mod kernel;
pub mod large_array;
pub mod memory;
pub mod push;
pub mod recorder;
pub mod spirv;
pub mod staging;
pub mod texel;
pub mod timing;

pub use buffer::{Binding, BufferDesc, GpuBuffer};
pub use caps::DeviceCaps;
pub use context::{Context, ContextDesc, Validation};
pub use error::{GpuError, GpuResult};
pub use host_buffer::{HostBuffer, HostDirection};
pub use host_clock::HostTimes;
pub use kernel::{Kernel, ShaderBlob};
pub use large_array::LargeArray;
pub use memory::{MemoryCategory, MemoryLedger, MemoryReport};
pub use push::{PushField, PushLayout};
pub use recorder::{InFlight, Recorder};
pub use timing::{KernelTime, TimingReport};
