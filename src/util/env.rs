//! Every `MSNERF_*` environment switch in one place, read once per process (issue 24 item 5). The GPU context logs
//! the ones that are set when it starts, and `msnerf train` records them in the run's `summary.json` with the
//! device and the MLP tiling, so a result can be traced to the switches it ran under.
//!
//! | variable | effect |
//! | --- | --- |
//! | `MSNERF_DEVICE` | device index or part of its name |
//! | `MSNERF_VALIDATION` | use the Khronos validation layer when installed |
//! | `MSNERF_REQUIRE_VALIDATION` | require it (`make test`) |
//! | `MSNERF_DISABLE_PUSH_DESCRIPTOR` | bind descriptors through pools (tests the fallback) |
//! | `MSNERF_DISABLE_F16` | no fp16 hidden activations (and no cooperative matrices) |
//! | `MSNERF_DISABLE_COOPMAT` | no cooperative-matrix (tensor-core) MLP kernels: the fp32 tiles instead |
//! | `MSNERF_POISON_BUFFERS` | fresh GPU buffers hold NaN bits (`make test`) |
//! | `MSNERF_MLP_TILING` | MLP kernel family and block sizes (benchmarks; `nn::mlp::MlpTiling`) |
//! | `MSNERF_HASH_BWD_RUN` | points per hash-grid backward invocation (default 8 on GPUs, 1 on CPU devices) |
//! | `MSNERF_HASH_TEXEL` | hash tables read as texel buffers: `1` on, `0` off (default: on CPU devices) |
//! | `MSNERF_HASH_ONE_DISPATCH` | hash-grid forward and input gradient in one dispatch for all levels: `1` always, `0` never (default: on GPUs for passes of up to 2^20 points) |
//! | `MSNERF_RAY_LANES` | per-ray kernels over 32 lanes per ray: `1` on, `0` off (default: on GPUs) |

use std::sync::OnceLock;

/// The switches as read at first use.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct EnvSettings {
    pub device: Option<String>,
    pub validation: bool,
    pub require_validation: bool,
    pub disable_push_descriptor: bool,
    pub disable_f16: bool,
    pub disable_coopmat: bool,
    pub poison_buffers: bool,
    pub mlp_tiling: Option<String>,
    pub hash_bwd_run: Option<String>,
    pub hash_texel: Option<String>,
    pub hash_one_dispatch: Option<String>,
    pub ray_lanes: Option<String>,
}

fn text(name: &str) -> Option<String> {
    std::env::var(name).ok().filter(|v| !v.is_empty())
}

fn flag(name: &str) -> bool {
    text(name).is_some_and(|v| v != "0")
}

impl EnvSettings {
    /// Reads the environment now (use [`settings`] for the process-wide copy).
    pub fn read() -> Self {
        EnvSettings {
            device: text("MSNERF_DEVICE"),
            validation: flag("MSNERF_VALIDATION"),
            require_validation: flag("MSNERF_REQUIRE_VALIDATION"),
            disable_push_descriptor: flag("MSNERF_DISABLE_PUSH_DESCRIPTOR"),
            disable_f16: flag("MSNERF_DISABLE_F16"),
            disable_coopmat: flag("MSNERF_DISABLE_COOPMAT"),
            poison_buffers: flag("MSNERF_POISON_BUFFERS"),
            mlp_tiling: text("MSNERF_MLP_TILING"),
            hash_bwd_run: text("MSNERF_HASH_BWD_RUN"),
            hash_texel: text("MSNERF_HASH_TEXEL"),
            hash_one_dispatch: text("MSNERF_HASH_ONE_DISPATCH"),
            ray_lanes: text("MSNERF_RAY_LANES"),
        }
    }

    /// `NAME=value` for every switch that is set, in the table's order.
    pub fn set_switches(&self) -> Vec<String> {
        let mut v = Vec::new();
        let mut on = |name: &str, set: bool| {
            if set {
                v.push(format!("{name}=1"));
            }
        };
        on("MSNERF_VALIDATION", self.validation);
        on("MSNERF_REQUIRE_VALIDATION", self.require_validation);
        on("MSNERF_DISABLE_PUSH_DESCRIPTOR", self.disable_push_descriptor);
        on("MSNERF_DISABLE_F16", self.disable_f16);
        on("MSNERF_DISABLE_COOPMAT", self.disable_coopmat);
        on("MSNERF_POISON_BUFFERS", self.poison_buffers);
        for (name, value) in [
            ("MSNERF_DEVICE", &self.device),
            ("MSNERF_MLP_TILING", &self.mlp_tiling),
            ("MSNERF_HASH_BWD_RUN", &self.hash_bwd_run),
            ("MSNERF_HASH_TEXEL", &self.hash_texel),
            ("MSNERF_HASH_ONE_DISPATCH", &self.hash_one_dispatch),
            ("MSNERF_RAY_LANES", &self.ray_lanes),
        ] {
            if let Some(x) = value {
                v.push(format!("{name}={x}"));
            }
        }
        v
    }
}

/// The process-wide switches, read at first use.
pub fn settings() -> &'static EnvSettings {
    static S: OnceLock<EnvSettings> = OnceLock::new();
    S.get_or_init(EnvSettings::read)
}
