//! YAML inputs checked for values serde accepts but no setting can use: `.nan` and `.inf`. The first one found is named by its key path (`boxes[2].center[0]`), so a scene or a
//! model profile is refused before any of it runs.

/// The key path of the first non-finite number in `text`'s YAML, if any (`None` too when it does not parse:
/// serde's own error names that).
pub fn first_non_finite(text: &str) -> Option<String> {
    let v: serde_yaml::Value = serde_yaml::from_str(text).ok()?;
    find(&v, String::new())
}

fn find(v: &serde_yaml::Value, path: String) -> Option<String> {
    match v {
        serde_yaml::Value::Number(n) => n.as_f64().filter(|x| !x.is_finite()).map(|_| path),
        serde_yaml::Value::Sequence(s) => s.iter().enumerate().find_map(|(i, e)| find(e, format!("{path}[{i}]"))),
        serde_yaml::Value::Mapping(m) => m.iter().find_map(|(k, e)| {
            let key = match k {
                serde_yaml::Value::String(s) => s.clone(),
                other => serde_yaml::to_string(other).unwrap_or_default().trim().to_string(),
            };
            find(e, if path.is_empty() { key } else { format!("{path}.{key}") })
        }),
        serde_yaml::Value::Tagged(t) => find(&t.value, path),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::first_non_finite;

    #[test]
    fn the_first_nan_or_inf_is_named_by_its_key_path() {
        assert_eq!(first_non_finite("a: 1\nb: [1, 2.5]\n"), None);
        assert_eq!(
            first_non_finite("a: 1\nboxes:\n  - {center: [0, 1]}\n  - {center: [.nan, 0]}\n").as_deref(),
            Some("boxes[1].center[0]")
        );
        assert_eq!(first_non_finite("x: {y: -.inf}").as_deref(), Some("x.y"));
        assert_eq!(first_non_finite("x: [unclosed"), None);
    }
}
