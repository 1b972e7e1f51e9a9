//! `ConfigError`: a model profile that cannot be read or is out of range, naming the file (or built-in profile)
//! and the key (the project's `data/error.rs` convention).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The profile file could not be read.
    #[error("{}: {reason}", path.display())]
    Read { path: PathBuf, reason: String },
    /// A YAML problem (key and line) or a value out of range (key); `profile` names the file or built-in profile
    /// (empty while parsing text that has no name yet).
    #[error("{}{reason}", if profile.is_empty() { String::new() } else { format!("{profile}: ") })]
    Invalid { profile: String, reason: String },
}

impl ConfigError {
    /// A problem at a key (the profile is named later, [`ConfigError::in_profile`]).
    pub fn key(reason: impl Into<String>) -> Self {
        ConfigError::Invalid { profile: String::new(), reason: reason.into() }
    }

    /// Names the profile a parse or validation error belongs to.
    pub fn in_profile(self, name: impl Into<String>) -> Self {
        match self {
            ConfigError::Invalid { profile, reason } if profile.is_empty() => {
                ConfigError::Invalid { profile: name.into(), reason }
            }
            e => e,
        }
    }
}
