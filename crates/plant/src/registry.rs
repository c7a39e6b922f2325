//! What of the parameter registry knows the plant: its table ([`params`]) and serde errors
//! naming the effect catalogue ([`from_serde`]). Read through [`crate::spec`], which adds
//! the registry types of `ehactl-types` (crates/types/src/spec.rs).

use crate::params::PlantParams;
use ehactl_types::spec::{expectation, table, ConfigError, Param};
use std::sync::LazyLock;

/// The plant's parameters, generated once from the `#[param(...)]` declarations on the fields
/// of [`PlantParams`] (`#[derive(Params)]`, crate `ehactl-params-derive`), in declaration
/// order. Controller, setpoint, supervisor and run parameters are declared in `ehactl-config`.
pub fn params() -> &'static [Param] {
    static TABLE: LazyLock<Vec<Param>> = LazyLock::new(|| table::<PlantParams>(""));
    &TABLE
}

/// Turn a serde error (from `serde_path_to_error`) into a [`ConfigError`] naming the full
/// path and the expected unit.
pub fn from_serde(
    prefix: &str,
    err: serde_path_to_error::Error<toml::de::Error>,
    tables: &[&[Param]],
) -> ConfigError {
    let mut path = err.path().to_string();
    if path == "." {
        path.clear();
    }
    let full = |p: &str| -> String {
        match (prefix.is_empty(), p.is_empty()) {
            (true, _) => p.to_string(),
            (false, true) => prefix.to_string(),
            (false, false) => format!("{prefix}.{p}"),
        }
    };
    let inner = err.into_inner();
    let msg = inner.message().to_string();
    if let Some(field) = between(&msg, "missing field `", "`") {
        let base = full(&path);
        let fp = if base.is_empty() {
            field.to_string()
        } else {
            format!("{base}.{field}")
        };
        let exp = expectation(tables, &fp);
        return ConfigError::new(fp, format!("missing required field; {exp}"));
    }
    if let Some(field) = between(&msg, "unknown field `", "`") {
        // serde_path_to_error's path already ends with the unknown key.
        let fp = full(&path);
        let base = fp
            .strip_suffix(field)
            .map(|b| b.trim_end_matches('.').to_string())
            .unwrap_or_default();
        let fp = if fp.is_empty() { field.to_string() } else { fp };
        if base == "effects" {
            return ConfigError::new(
                fp,
                format!(
                    "unknown effect id `{field}`; expected one of: {}",
                    crate::effects::EffectId::ALL
                        .iter()
                        .map(|e| e.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            );
        }
        let rest = msg.split(", expected").nth(1).unwrap_or("").trim();
        return ConfigError::new(
            fp,
            format!(
                "unknown field; expected{}",
                if rest.is_empty() {
                    " no such field".to_string()
                } else {
                    format!(" {rest}")
                }
            ),
        );
    }
    let fp = full(&path);
    let exp = expectation(tables, &fp);
    ConfigError::new(fp, format!("{msg}; {exp}"))
}

fn between<'a>(s: &'a str, start: &str, end: &str) -> Option<&'a str> {
    let i = s.find(start)? + start.len();
    let j = s[i..].find(end)? + i;
    Some(&s[i..j])
}
