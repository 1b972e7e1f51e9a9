//! `extends:` in a model profile: a profile may name another (a built-in profile, or a YAML file relative to its
//! own folder) and give only what differs. The base is read first (it may extend another in turn, up to
//! [`MAX_DEPTH`] levels), then the profile's keys are laid over it: mappings merge key by key, any other value
//! (a number, a string, a list) replaces the base's.

use std::path::{Path, PathBuf};

use super::config::ModelConfig;
use super::config_error::ConfigError;
use serde_yaml::Value;

/// Profiles extend each other at most this deep (a cycle is refused when it reaches it).
pub const MAX_DEPTH: usize = 8;

/// The profile `text` (from the folder `dir`, None for a built-in) with its `extends:` chain resolved; None when it
/// extends nothing (the caller then parses the text itself and keeps YAML's line numbers in its errors).
pub fn resolve_extends(text: &str, dir: Option<&Path>) -> Result<Option<Value>, ConfigError> {
    let v: Value = serde_yaml::from_str(text).map_err(|e| ConfigError::key(e.to_string()))?;
    if v.get("extends").is_none() {
        return Ok(None);
    }
    Ok(Some(merged(v, dir, 0)?))
}

fn merged(mut v: Value, dir: Option<&Path>, depth: usize) -> Result<Value, ConfigError> {
    let Some(base) = v.as_mapping_mut().and_then(|m| m.remove("extends")) else { return Ok(v) };
    let base = base.as_str().ok_or_else(|| ConfigError::key("extends: a profile name or a YAML file expected"))?;
    if depth + 1 >= MAX_DEPTH {
        return Err(ConfigError::key(format!(
            "extends: more than {MAX_DEPTH} levels (do two profiles extend each other?)"
        )));
    }
    let (text, base_dir): (String, Option<PathBuf>) = match ModelConfig::BUILTIN.iter().find(|(n, _)| *n == base) {
        Some((_, t)) => (t.to_string(), None),
        None => {
            let p = dir.map_or_else(|| PathBuf::from(base), |d| d.join(base));
            let t =
                std::fs::read_to_string(&p).map_err(|e| ConfigError::key(format!("extends: {}: {e}", p.display())))?;
            (t, p.parent().map(Path::to_path_buf))
        }
    };
    if let Some(key) = crate::util::yaml::first_non_finite(&text) {
        return Err(ConfigError::key(format!("extends {base}: {key}: not a finite number")));
    }
    let b: Value = serde_yaml::from_str(&text).map_err(|e| ConfigError::key(format!("extends {base}: {e}")))?;
    let mut out = merged(b, base_dir.as_deref(), depth + 1)?;
    lay_over(&mut out, v);
    Ok(out)
}

/// `over`'s keys laid over `base`: mappings key by key, anything else replaced.
fn lay_over(base: &mut Value, over: Value) {
    match (base, over) {
        (Value::Mapping(b), Value::Mapping(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(bv) => lay_over(bv, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_profile_extends_a_builtin_and_a_file_and_cycles_are_named() {
        let demo = ModelConfig::resolve("demo").unwrap();
        let c = ModelConfig::parse("extends: demo\nname: mine\nfield: {hidden_dim: 64}\ntrainer: {max_steps: 123}\n")
            .unwrap();
        assert_eq!((c.name.as_str(), c.field.hidden_dim, c.trainer.max_steps), ("mine", 64, 123));
        // Everything else is the base's.
        assert_eq!(c.field.num_layers, demo.field.num_layers);
        assert_eq!(c.field.grid.n_levels, demo.field.grid.n_levels);
        assert_eq!(c.proposals.len(), demo.proposals.len());
        // A file relative to the extending file's folder, itself extending a built-in.
        let dir = std::env::temp_dir().join(format!("msnerf-extends-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("sub/base.yaml"), "extends: tiny\ntrainer: {max_steps: 7}\n").unwrap();
        std::fs::write(dir.join("top.yaml"), "extends: sub/base.yaml\nname: top\n").unwrap();
        let t = ModelConfig::load(&dir.join("top.yaml")).unwrap();
        assert_eq!((t.name.as_str(), t.trainer.max_steps), ("top", 7));
        assert_eq!(t.field.hidden_dim, ModelConfig::resolve("tiny").unwrap().field.hidden_dim);
        // A cycle, a missing base, an unknown key over a base: each named.
        std::fs::write(dir.join("a.yaml"), "extends: b.yaml\n").unwrap();
        std::fs::write(dir.join("b.yaml"), "extends: a.yaml\n").unwrap();
        let e = ModelConfig::load(&dir.join("a.yaml")).unwrap_err().to_string();
        assert!(e.contains("extends") && e.contains("levels"), "{e}");
        let e = ModelConfig::parse("extends: no-such.yaml\n").unwrap_err().to_string();
        assert!(e.contains("extends: no-such.yaml"), "{e}");
        let e = ModelConfig::parse("extends: demo\nfield: {hiden_dim: 3}\n").unwrap_err().to_string();
        assert!(e.contains("hiden_dim"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
