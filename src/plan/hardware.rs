//! Hardware profiles (`configs/hardware/*.yaml`): the VRAM and host-memory budgets of one machine, the headroom
//! kept free on each, the device limits the planner needs when no such device is present, the training and
//! evaluation ray counts, and the host image cache's N and M (paper §6.1-6.2, Tables 8 and 9). Unknown keys are
//! errors; every error names the file (or built-in profile) and the key.

use super::error::PlanError;
use serde::{Deserialize, Serialize};
use std::path::Path;

const GIB: f64 = (1u64 << 30) as f64;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HardwareProfile {
    pub name: String,
    /// What the profile describes, in one line.
    #[serde(default)]
    pub description: String,
    pub gpu: GpuProfile,
    pub host: HostProfile,
    pub trainer: TrainerProfile,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpuProfile {
    /// Part of the Vulkan device name this profile is for: when such a device is present, `msnerf plan` takes
    /// byte counts and limits from it instead of the rule and limits below.
    #[serde(default)]
    pub device_name: Option<String>,
    /// Device-local memory of the card, GiB.
    pub vram_gib: f64,
    /// Kept free for the driver, the allocator's block slack and other processes, GiB.
    pub headroom_gib: f64,
    /// `maxStorageBufferRange`: the largest single binding (and, with `max_memory_allocation_size`, the chunk
    /// size of the parameter store).
    pub max_storage_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    /// With bufferDeviceAddress each chunked array also has a chunk table.
    #[serde(default = "yes")]
    pub buffer_device_address: bool,
    /// Footprint rule used when planning without the device: sizes round up to this many bytes...
    #[serde(default = "align")]
    pub alignment: u64,
    /// ...and no buffer is smaller than this.
    #[serde(default = "min_bytes")]
    pub min_buffer_bytes: u64,
}

fn yes() -> bool {
    true
}
fn align() -> u64 {
    256
}
fn min_bytes() -> u64 {
    16
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostProfile {
    /// Host memory of the machine, GiB.
    pub memory_gib: f64,
    /// Kept free for the OS, the process and the ray batch, GiB; the image cache may use the rest.
    pub headroom_gib: f64,
    #[serde(default)]
    pub cache: CacheProfile,
}

/// The image cache's resident set N and resampling period M. Left out, they follow Table 8's rules scaled to
/// the host budget: N as many images as the cache budget holds, M = 2 N steps.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CacheProfile {
    #[serde(default)]
    pub n_resident: Option<usize>,
    #[serde(default)]
    pub resample_every: Option<u64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainerProfile {
    /// Training rays per optimiser step (Table 9's "training ray batch size").
    pub rays_per_batch: usize,
    /// Rays per GPU pass: activation memory scales with this, not with the batch.
    pub rays_per_chunk: usize,
    /// Rays per evaluation pass (Table 9's "evaluation ray batch size").
    pub eval_rays_per_chunk: usize,
}

/// Table 8's ratio of the resampling period to the resident set (M = 2 N in both rows).
pub const TABLE8_M_PER_N: u64 = 2;

impl HardwareProfile {
    /// The built-in profiles.
    pub const BUILTIN: [&'static str; 3] = ["rtx2080ti-11gb", "a100-80gb", "lavapipe"];

    /// A built-in profile by name, or a path to a YAML file.
    pub fn resolve(name_or_path: &str) -> Result<Self, PlanError> {
        let text = match name_or_path {
            "rtx2080ti-11gb" => Some(include_str!("../../configs/hardware/rtx2080ti-11gb.yaml")),
            "a100-80gb" => Some(include_str!("../../configs/hardware/a100-80gb.yaml")),
            "lavapipe" => Some(include_str!("../../configs/hardware/lavapipe.yaml")),
            _ => None,
        };
        match text {
            Some(t) => Self::parse(t).map_err(|e| e.in_profile(format!("built-in hardware profile {name_or_path}"))),
            None => {
                let p = Path::new(name_or_path);
                if !p.exists() && !name_or_path.contains(['/', '.']) {
                    return Err(PlanError::UnknownProfile {
                        name: name_or_path.to_string(),
                        builtin: Self::BUILTIN.join(", "),
                    });
                }
                Self::load(p)
            }
        }
    }

    pub fn load(path: &Path) -> Result<Self, PlanError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| PlanError::Read { path: path.to_path_buf(), reason: e.to_string() })?;
        Self::parse(&text).map_err(|e| e.in_profile(path.display().to_string()))
    }

    /// Parses and validates; YAML errors name the key and line, validation errors the key.
    pub fn parse(text: &str) -> Result<Self, PlanError> {
        let p: Self = serde_yaml::from_str(text).map_err(|e| PlanError::key(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    pub fn validate(&self) -> Result<(), PlanError> {
        let g = &self.gpu;
        let pos = |v: f64, key: &str| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(PlanError::key(format!("{key}: must be a finite number >= 0, got {v}")))
            }
        };
        pos(g.vram_gib, "gpu.vram_gib")?;
        pos(g.headroom_gib, "gpu.headroom_gib")?;
        pos(self.host.memory_gib, "host.memory_gib")?;
        pos(self.host.headroom_gib, "host.headroom_gib")?;
        if g.headroom_gib >= g.vram_gib {
            return Err(PlanError::key(format!(
                "gpu.headroom_gib ({}) must be less than gpu.vram_gib ({})",
                g.headroom_gib, g.vram_gib
            )));
        }
        if self.host.headroom_gib >= self.host.memory_gib {
            return Err(PlanError::key(format!(
                "host.headroom_gib ({}) must be less than host.memory_gib ({})",
                self.host.headroom_gib, self.host.memory_gib
            )));
        }
        if !g.alignment.is_power_of_two() {
            return Err(PlanError::key(format!("gpu.alignment: must be a power of two, got {}", g.alignment)));
        }
        if g.min_buffer_bytes == 0 {
            return Err(PlanError::key("gpu.min_buffer_bytes: must be > 0"));
        }
        if g.max_storage_buffer_range < 1 << 16 || g.max_memory_allocation_size < 1 << 16 {
            return Err(PlanError::key(
                "gpu.max_storage_buffer_range and gpu.max_memory_allocation_size: must be >= 65536",
            ));
        }
        let t = &self.trainer;
        for (v, key) in [
            (t.rays_per_batch, "trainer.rays_per_batch"),
            (t.rays_per_chunk, "trainer.rays_per_chunk"),
            (t.eval_rays_per_chunk, "trainer.eval_rays_per_chunk"),
        ] {
            if v == 0 {
                return Err(PlanError::key(format!("{key}: must be > 0")));
            }
        }
        if self.host.cache.n_resident == Some(0) || self.host.cache.resample_every == Some(0) {
            return Err(PlanError::key("host.cache.n_resident and host.cache.resample_every: must be > 0 when given"));
        }
        Ok(())
    }

    /// Bytes the planner may place on the device: VRAM minus headroom.
    pub fn vram_budget_bytes(&self) -> u64 {
        ((self.gpu.vram_gib - self.gpu.headroom_gib) * GIB) as u64
    }

    /// Bytes the image cache may use at its peak: host memory minus headroom.
    pub fn host_budget_bytes(&self) -> u64 {
        ((self.host.memory_gib - self.host.headroom_gib) * GIB) as u64
    }
}

impl HardwareProfile {
    /// A profile for the device in `ctx` (`--hardware auto`): its largest device-local heap with 10% (at least
    /// 0.5 GiB) kept free, its limits, this machine's host memory with 25% (at least 2 GiB) kept free, and the
    /// model's ray counts (the caller fits the chunks).
    pub fn auto(ctx: &crate::gpu::Context, rays: TrainerProfile) -> Self {
        let c = ctx.caps();
        let vram = c.device_local_bytes() as f64 / GIB;
        let host = host_memory_bytes().unwrap_or(16 << 30) as f64 / GIB;
        Self {
            name: format!("auto ({})", c.name),
            description: "this device's memory, found through the planner".into(),
            gpu: GpuProfile {
                device_name: Some(c.name.clone()),
                vram_gib: vram,
                headroom_gib: (vram * 0.1).max(0.5).min(vram * 0.5),
                max_storage_buffer_range: c.max_storage_buffer_range,
                max_memory_allocation_size: c.max_memory_allocation_size,
                buffer_device_address: c.buffer_device_address,
                alignment: align(),
                min_buffer_bytes: min_bytes(),
            },
            host: HostProfile {
                memory_gib: host,
                headroom_gib: (host * 0.25).max(2.0).min(host * 0.5),
                cache: CacheProfile::default(),
            },
            trainer: rays,
        }
    }

    /// Whether this profile names the device in `ctx`.
    pub fn matches(&self, ctx: &crate::gpu::Context) -> bool {
        let name = ctx.caps().name.to_lowercase();
        self.gpu.device_name.as_ref().is_some_and(|n| name.contains(&n.to_lowercase()))
    }
}

/// MemTotal from /proc/meminfo (Linux), bytes.
pub fn host_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_profiles_parse() {
        for n in HardwareProfile::BUILTIN {
            let p = HardwareProfile::resolve(n).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(p.name, n);
            assert!(p.vram_budget_bytes() > 0 && p.host_budget_bytes() > 0);
        }
    }
}
