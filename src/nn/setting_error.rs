//! `SettingError`: a network, encoding, tiling or optimiser setting out of range, naming the key (`width`,
//! `n_levels`, `wgrad_tile`, `group "field"`) and what was expected. The model profile names the file around it
//! (`nerf::config_error::ConfigError`); the GPU layer reports it as `GpuError::Config`.

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct SettingError {
    pub key: String,
    pub reason: String,
}

impl SettingError {
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        SettingError { key: key.into(), reason: reason.into() }
    }
}
