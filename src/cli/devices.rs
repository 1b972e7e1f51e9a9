//! `msnerf devices`: every Vulkan device with a compute queue and its capabilities, as a table or `--json`.
//! Marks the device msnerf would pick by default (or the one `--device` names).

use super::Cli;
use crate::gpu::context::list_devices;
use crate::gpu::DeviceCaps;

#[derive(clap::Args, Debug)]
pub struct DevicesArgs {
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
}

fn mib(b: u64) -> String {
    format!("{} MiB", b >> 20)
}

fn rows(c: &DeviceCaps) -> Vec<(&'static str, String)> {
    vec![
        ("type", c.device_type.clone()),
        ("driver", format!("{} {}", c.driver_name, c.driver_info)),
        ("vulkan", c.api_version.clone()),
        ("device-local memory", mib(c.device_local_bytes())),
        ("max storage binding", mib(c.max_storage_buffer_range)),
        ("max allocation", mib(c.max_memory_allocation_size)),
        ("shared memory", format!("{} KiB", c.max_shared_memory / 1024)),
        ("subgroup size", format!("{} (min {}, max {})", c.subgroup_size, c.min_subgroup_size, c.max_subgroup_size)),
        ("workgroup invocations", c.max_workgroup_invocations.to_string()),
        ("workgroup count", format!("{:?}", c.max_workgroup_count)),
        ("push constants", format!("{} B", c.max_push_constants_size)),
        ("f32 atomic add", yes(c.float32_atomic_add)),
        ("fp16 arithmetic / storage", format!("{} / {}", yes(c.shader_float16), yes(c.storage_buffer_16bit))),
        ("buffer device address", yes(c.buffer_device_address)),
        ("push descriptors", yes(c.push_descriptor)),
        (
            "cooperative matrices (MLP)",
            format!(
                "{} / kernels in this build: {}",
                yes(c.cooperative_matrix),
                if crate::shaders::MLP_COOP_LAYER.is_some() { "yes" } else { "no (--features shaderc-from-source)" }
            ),
        ),
        ("timestamps", c.timestamp_period_ns.map(|p| format!("{p} ns/tick")).unwrap_or_else(|| "no".into())),
    ]
}

fn yes(b: bool) -> String {
    if b { "yes" } else { "no" }.into()
}

pub fn run(cli: &Cli, args: &DevicesArgs) -> anyhow::Result<()> {
    let devices = list_devices()?;
    if devices.is_empty() {
        anyhow::bail!("{}", crate::gpu::GpuError::NoDevice(String::new()));
    }
    let chosen = crate::gpu::context::default_device_index(&devices, cli.context_desc().device.as_deref())?;
    if args.json {
        let v: Vec<serde_json::Value> = devices
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let mut v = serde_json::to_value(c).expect("DeviceCaps serialises");
                v["index"] = i.into();
                v["selected"] = (i == chosen).into();
                v
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    for (i, c) in devices.iter().enumerate() {
        let mark = if i == chosen { "  <- selected" } else { "" };
        println!("[{i}] {}{mark}", c.name);
        for (k, v) in rows(c) {
            println!("    {k:<26} {v}");
        }
    }
    Ok(())
}
