//! `PlanError`: every way planning memory can fail, naming the profile (built-in name or file) and the key, the
//! buffer layout, or the budget that was exceeded (the project's `data/error.rs` convention).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// A hardware profile file could not be read.
    #[error("{}: {reason}", path.display())]
    Read { path: PathBuf, reason: String },
    /// A hardware profile is malformed or out of range: `profile` names it (empty while parsing text that has no
    /// name yet), `reason` the key.
    #[error("{}{reason}", if profile.is_empty() { String::new() } else { format!("{profile}: ") })]
    Profile { profile: String, reason: String },
    /// Neither a built-in profile nor a file.
    #[error("{name}: no such hardware profile (built-in: {builtin}, or a YAML file)")]
    UnknownProfile { name: String, builtin: String },
    /// The model's parameter layout or buffer shapes cannot be laid out.
    #[error("{0}")]
    Layout(String),
    /// Training does not fit the profile's budgets; `hint` names the largest chunk that would.
    #[error("training does not fit {profile}: {problems}{hint}")]
    DoesNotFit { profile: String, problems: String, hint: String },
}

impl PlanError {
    /// A profile problem at `key` (the profile is named later, [`PlanError::in_profile`]).
    pub fn key(reason: impl Into<String>) -> Self {
        PlanError::Profile { profile: String::new(), reason: reason.into() }
    }

    /// Names the profile a parse or validation error belongs to.
    pub fn in_profile(self, name: impl Into<String>) -> Self {
        match self {
            PlanError::Profile { profile, reason } if profile.is_empty() => {
                PlanError::Profile { profile: name.into(), reason }
            }
            e => e,
        }
    }
}
