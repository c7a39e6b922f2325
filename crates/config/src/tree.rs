//! The registry's checks on a parsed TOML tree: dotted-path access ([`get`], [`get_mut`]) and
//! [`check_tree`], which normalises integers to floats and checks every declared parameter's
//! type and range before serde reads the sections, and [`from_serde`], which names the
//! registry path and expected unit of an error serde raises while reading them.
//!
//! They live here, with the loader that calls them, and not beside the registry types in
//! `ehactl-types` (crates/types/src/spec.rs): the control laws declare their parameters
//! through those types, and `ehactl-types` compiles no TOML parser
//! (tests/python/test_crate_layers.py).

use ehactl_plant::spec::{expectation, readable, ConfigError, Kind, Param};

/// Get the value at a dotted path in a TOML tree.
pub fn get<'a>(root: &'a toml::Value, path: &str) -> Option<&'a toml::Value> {
    let mut cur = root;
    for key in path.split('.') {
        cur = cur.as_table()?.get(key)?;
    }
    Some(cur)
}

/// Get a mutable value at a dotted path.
pub fn get_mut<'a>(root: &'a mut toml::Value, path: &str) -> Option<&'a mut toml::Value> {
    let mut cur = root;
    for key in path.split('.') {
        cur = cur.as_table_mut()?.get_mut(key)?;
    }
    Some(cur)
}

/// Normalise integers to floats for float parameters (TOML `5000` for a float field),
/// then check every declared parameter that is present: type, finiteness and range.
pub fn check_tree(root: &mut toml::Value, tables: &[&[Param]]) -> Result<(), ConfigError> {
    for param in tables.iter().flat_map(|t| t.iter()) {
        let Some(v) = get_mut(root, param.path) else {
            continue;
        };
        let bad = |what: String| {
            ConfigError::new(
                param.path,
                format!("{what}; {}", expectation(tables, param.path)),
            )
        };
        match param.kind {
            Kind::Float | Kind::Integer => {
                let x = match v {
                    toml::Value::Float(f) => *f,
                    toml::Value::Integer(i) => *i as f64,
                    other => {
                        return Err(bad(format!(
                            "wrong type: got {} `{}`",
                            other.type_str(),
                            other
                        )))
                    }
                };
                if param.kind == Kind::Float {
                    *v = toml::Value::Float(x);
                } else if x.fract() != 0.0 {
                    return Err(bad(format!("got {}, not an integer", readable(x))));
                }
                if !param.range.admits(x) {
                    let what = if x.is_finite() {
                        format!("value {} is out of range", readable(x))
                    } else {
                        format!("value {x} is not finite")
                    };
                    return Err(bad(what));
                }
            }
            Kind::Bool => {
                if !v.is_bool() {
                    return Err(ConfigError::new(
                        param.path,
                        format!(
                            "wrong type: got {} `{}`; expected true or false ({})",
                            v.type_str(),
                            v,
                            param.description
                        ),
                    ));
                }
            }
            Kind::Choice(choices) => {
                if !v.as_str().is_some_and(|x| choices.contains(&x)) {
                    let list = choices
                        .iter()
                        .map(|c| format!("\"{c}\""))
                        .collect::<Vec<_>>()
                        .join(", ");
                    return Err(ConfigError::new(
                        param.path,
                        format!("got `{v}`; expected one of {list} ({})", param.description),
                    ));
                }
            }
            Kind::FloatArray => {
                let Some(items) = v.as_array_mut() else {
                    return Err(bad(format!("wrong type: got {}", v.type_str())));
                };
                for (i, item) in items.iter_mut().enumerate() {
                    let x = match item {
                        toml::Value::Float(f) => *f,
                        toml::Value::Integer(n) => *n as f64,
                        other => {
                            return Err(bad(format!(
                                "element {i} has wrong type {}",
                                other.type_str()
                            )))
                        }
                    };
                    *item = toml::Value::Float(x);
                    if !param.range.admits(x) {
                        return Err(bad(format!(
                            "element {i} = {} is out of range",
                            readable(x)
                        )));
                    }
                }
            }
        }
    }
    Ok(())
}

/// Turn a serde error (from `serde_path_to_error`) into a [`ConfigError`] naming the full
/// path and the expected unit. `tables` are the registries the path is looked up in
/// (`crate::registries()`); an unknown key under `effects` lists the plant's effect ids.
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
                    ehactl_plant::EffectId::ALL
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
