//! Memory budgets (project issue 7): hardware profiles, the VRAM planner and the host-memory plan.
//!
//! - [`hardware`]: `configs/hardware/*.yaml`: budgets, headroom, device limits, ray counts, the cache's N and M.
//! - [`device`]: buffer footprints from the device (`Context::buffer_footprint`) or a documented rule.
//! - [`vram`]: every device buffer the trainer allocates, built from the trainer's own allocation code.
//! - [`host`]: the image cache's bytes, N and M (paper §6.1, Table 8).
//! - [`fit`]: the largest training and evaluation chunks that fit a budget; the whole plan for a profile.
//! - [`report`]: the text table `msnerf plan` prints.
//! - [`error`]: [`PlanError`], naming the profile and key, the layout, or the budget exceeded.

pub mod device;
pub mod error;
pub mod fit;
pub mod hardware;
pub mod host;
pub mod report;
pub mod train;
pub mod vram;

pub use device::{DeviceRule, Footprint};
pub use error::PlanError;
pub use fit::{plan, FitResult, Plan, PlanRequest};
pub use hardware::HardwareProfile;
pub use host::{DatasetShape, HostPlan};
pub use vram::{plan_vram, Part, RayCounts, VramEntry, VramPlan};
