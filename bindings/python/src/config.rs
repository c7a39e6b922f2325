//! `Config`: a validated rig config with dict-like access by dotted path. Every change is
//! validated by the same loader as the CLI (`RigConfig::from_value`), so a config that
//! Python accepts is one the 5 kHz loop accepts, and errors name the field and its unit.

use ehactl_config::{registries, tree, RigConfig};
use ehactl_plant::spec::{self, ConfigError, Kind};
use pyo3::exceptions::{PyKeyError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::path::PathBuf;

/// ConfigError → ValueError with the CLI's one-line message.
pub(crate) fn config_err(e: ConfigError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A validated rig configuration (TOML, SI units).
#[pyclass(module = "ehactl", name = "Config", from_py_object)]
#[derive(Clone)]
pub struct Config {
    /// The validated config.
    pub(crate) cfg: RigConfig,
    /// File it was loaded from, if any.
    pub(crate) source: Option<String>,
}

fn py_to_toml(v: &Bound<'_, PyAny>, path: &str) -> PyResult<toml::Value> {
    if v.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(v.extract::<bool>()?));
    }
    if v.is_instance_of::<PyInt>() {
        // TOML integers are 64-bit: a larger one (10**400) is refused naming the field,
        // not as a bare OverflowError.
        return v.extract::<i64>().map(toml::Value::Integer).map_err(|_| {
            let digits = v.str().map(|s| s.to_string()).unwrap_or_default();
            let shown = if digits.len() > 40 {
                format!("an integer of {} digits", digits.trim_start_matches('-').len())
            } else {
                digits
            };
            PyValueError::new_err(format!(
                "config error at `{path}`: {shown} does not fit a 64-bit integer (|value| ≤ 9.2e18); expected a value in the field's range (see ehactl.params())"
            ))
        });
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(v.extract::<f64>()?));
    }
    if v.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(v.extract::<String>()?));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut t = toml::Table::new();
        for (k, item) in d.iter() {
            let k: String = k.extract()?;
            let sub = format!("{path}.{k}");
            t.insert(k, py_to_toml(&item, &sub)?);
        }
        return Ok(toml::Value::Table(t));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() || v.hasattr("tolist")? {
        // numpy arrays and scalars expose tolist()
        let obj = if v.hasattr("tolist")? {
            v.call_method0("tolist")?
        } else {
            v.clone()
        };
        if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
            let mut out = Vec::new();
            for (i, item) in obj.try_iter()?.enumerate() {
                out.push(py_to_toml(&item?, &format!("{path}[{i}]"))?);
            }
            return Ok(toml::Value::Array(out));
        }
        return py_to_toml(&obj, path);
    }
    if let Ok(x) = v.extract::<f64>() {
        return Ok(toml::Value::Float(x));
    }
    Err(PyTypeError::new_err(format!(
        "config error at `{path}`: cannot store a Python {} in a config; expected a number, bool, string, list or dict",
        v.get_type().name()?
    )))
}

pub(crate) fn toml_to_py<'py>(py: Python<'py>, v: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        toml::Value::String(s) => PyString::new(py, s).into_any(),
        toml::Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        toml::Value::Float(f) => PyFloat::new(py, *f).into_any(),
        toml::Value::Boolean(b) => PyBool::new(py, *b).to_owned().into_any(),
        toml::Value::Datetime(d) => PyString::new(py, &d.to_string()).into_any(),
        toml::Value::Array(a) => {
            let l = PyList::empty(py);
            for item in a {
                l.append(toml_to_py(py, item)?)?;
            }
            l.into_any()
        }
        toml::Value::Table(t) => {
            let d = PyDict::new(py);
            for (k, item) in t {
                d.set_item(k, toml_to_py(py, item)?)?;
            }
            d.into_any()
        }
    })
}

fn leaves(prefix: &str, v: &toml::Value, out: &mut Vec<String>) {
    match v {
        toml::Value::Table(t) => {
            for (k, item) in t {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                leaves(&p, item, out);
            }
        }
        _ => out.push(prefix.to_string()),
    }
}

/// Insert `value` at dotted `path`, creating intermediate tables.
fn insert_path(root: &mut toml::Value, path: &str, value: toml::Value) -> Result<(), ConfigError> {
    if path.is_empty() || path.split('.').any(|k| k.is_empty()) {
        return Err(ConfigError::new(
            path,
            "not a valid dotted config path (e.g. \"valve.rated_flow\")",
        ));
    }
    let keys: Vec<&str> = path.split('.').collect();
    let mut cur = root;
    for (i, k) in keys.iter().enumerate() {
        let here = keys[..=i].join(".");
        let Some(t) = cur.as_table_mut() else {
            return Err(ConfigError::new(
                here,
                "is a value, not a section; cannot set a field below it",
            ));
        };
        if i + 1 == keys.len() {
            t.insert((*k).to_string(), value);
            return Ok(());
        }
        cur = t
            .entry((*k).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    }
    Ok(())
}

fn remove_path(root: &mut toml::Value, path: &str) -> Option<toml::Value> {
    let (parent, key) = match path.rsplit_once('.') {
        Some((p, k)) => (tree::get_mut(root, p)?, k),
        None => (root, path),
    };
    parent.as_table_mut()?.remove(key)
}

impl Config {
    fn apply(&mut self, edits: Vec<(String, Option<toml::Value>)>) -> PyResult<()> {
        let mut tree = self.cfg.to_value();
        for (path, value) in edits {
            match value {
                Some(v) => insert_path(&mut tree, &path, v).map_err(config_err)?,
                None => {
                    if remove_path(&mut tree, &path).is_none() {
                        return Err(PyKeyError::new_err(format!("config has no field `{path}`")));
                    }
                }
            }
        }
        self.cfg = RigConfig::from_value(tree).map_err(config_err)?;
        Ok(())
    }
}

#[pymethods]
impl Config {
    /// Load and validate a TOML rig config (path: str or PathLike).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Config> {
        if !path.exists() {
            return Err(pyo3::exceptions::PyFileNotFoundError::new_err((
                2,
                format!("config file not found: {}", path.display()),
                path.display().to_string(),
            )));
        }
        let cfg = RigConfig::load(&path).map_err(config_err)?;
        Ok(Config {
            cfg,
            source: Some(path.display().to_string()),
        })
    }

    /// Parse and validate TOML text.
    #[staticmethod]
    fn from_toml(text: &str) -> PyResult<Config> {
        let cfg = RigConfig::from_toml_str(text).map_err(config_err)?;
        Ok(Config { cfg, source: None })
    }

    /// Build and validate a config from a nested dict (the `to_dict()` form).
    #[staticmethod]
    fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Config> {
        let v = py_to_toml(d.as_any(), "")?;
        let cfg = RigConfig::from_value(v).map_err(config_err)?;
        Ok(Config { cfg, source: None })
    }

    /// The whole config as TOML text (defaults filled in).
    fn to_toml(&self) -> String {
        self.cfg.to_toml_string()
    }

    /// The whole config as a nested dict (defaults filled in).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        toml_to_py(py, &self.cfg.to_value())
    }

    /// Write the config as TOML to `path`; it loads back with `Config.load` and the CLI.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        let mut text = String::new();
        if let Some(src) = &self.source {
            text.push_str(&format!(
                "# derived from {src} by the ehactl Python package\n"
            ));
        }
        text.push_str(&self.cfg.to_toml_string());
        std::fs::write(&path, text).map_err(|e| {
            pyo3::exceptions::PyOSError::new_err(format!(
                "cannot write config {}: {e}",
                path.display()
            ))
        })
    }

    /// Value at a dotted path, e.g. `cfg["control.pi.kp"]` (V/V); sections come as dicts.
    fn __getitem__<'py>(&self, py: Python<'py>, path: &str) -> PyResult<Bound<'py, PyAny>> {
        let tree = self.cfg.to_value();
        match tree::get(&tree, path) {
            Some(v) => toml_to_py(py, v),
            None => Err(PyKeyError::new_err(format!(
                "config has no field `{path}`{}",
                match spec::find(&registries(), path) {
                    Some(p) => format!(
                        " (a known parameter in {} whose section is absent; set it to add it)",
                        p.unit
                    ),
                    None => String::new(),
                }
            ))),
        }
    }

    /// Set a value by dotted path and re-validate the whole config; raises ValueError naming
    /// the field and its expected unit when the result is invalid (the config is unchanged).
    fn __setitem__(&mut self, path: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let v = py_to_toml(value, path)?;
        self.apply(vec![(path.to_string(), Some(v))])
    }

    /// Remove an optional field or section (e.g. `del cfg["effects.sensor_tone"]`).
    fn __delitem__(&mut self, path: &str) -> PyResult<()> {
        self.apply(vec![(path.to_string(), None)])
    }

    fn __contains__(&self, path: &str) -> bool {
        tree::get(&self.cfg.to_value(), path).is_some()
    }

    /// Set several fields at once (dict of dotted path → value), validated together.
    fn update(&mut self, values: &Bound<'_, PyDict>) -> PyResult<()> {
        let mut edits = Vec::new();
        for (k, v) in values.iter() {
            let k: String = k.extract()?;
            let tv = py_to_toml(&v, &k)?;
            edits.push((k, Some(tv)));
        }
        self.apply(edits)
    }

    /// A copy with several fields changed (dict of dotted path → value).
    fn with_values(&self, values: &Bound<'_, PyDict>) -> PyResult<Config> {
        let mut c = self.clone();
        c.update(values)?;
        Ok(c)
    }

    /// Dotted paths of every leaf value in the config.
    fn keys(&self) -> Vec<String> {
        let mut out = Vec::new();
        leaves("", &self.cfg.to_value(), &mut out);
        out
    }

    /// Unit of a registered numeric parameter ("-" dimensionless), None if not registered.
    #[staticmethod]
    fn unit(path: &str) -> Option<&'static str> {
        spec::find(&registries(), path).map(|p| p.unit)
    }

    /// Independent copy.
    fn copy(&self) -> Config {
        self.clone()
    }

    fn __copy__(&self) -> Config {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Config {
        self.clone()
    }

    /// Control period 1 / run.control_rate_hz (s).
    #[getter]
    fn control_dt(&self) -> f64 {
        self.cfg.timebase().period()
    }

    /// Rig name (`rig.name`).
    #[getter]
    fn name(&self) -> String {
        self.cfg.rig.name.clone()
    }

    /// Control mode: "force", "position" or "open_loop".
    #[getter]
    fn mode(&self) -> String {
        match self.cfg.control.mode {
            ehactl_config::ControlMode::Force => "force",
            ehactl_config::ControlMode::Position => "position",
            ehactl_config::ControlMode::OpenLoop => "open_loop",
        }
        .to_string()
    }

    /// File the config was loaded from, or None.
    #[getter]
    fn source(&self) -> Option<String> {
        self.source.clone()
    }

    fn __eq__(&self, other: &Config) -> bool {
        self.cfg == other.cfg
    }

    fn __repr__(&self) -> String {
        format!(
            "Config(name={:?}, mode={:?}, control_rate_hz={}, duration={} s{})",
            self.cfg.rig.name,
            self.mode(),
            self.cfg.run.control_rate_hz,
            self.cfg.run.duration,
            match &self.source {
                Some(s) => format!(", source={s:?}"),
                None => String::new(),
            }
        )
    }

    // Pickling (for multiprocessing users): TOML text round trip.
    fn __getstate__(&self) -> String {
        self.cfg.to_toml_string()
    }

    fn __setstate__(&mut self, state: &str) -> PyResult<()> {
        self.cfg = RigConfig::from_toml_str(state).map_err(config_err)?;
        Ok(())
    }

    fn __getnewargs__(&self) -> (String,) {
        (self.cfg.to_toml_string(),)
    }

    #[new]
    #[pyo3(signature = (toml_text = None))]
    fn py_new(toml_text: Option<&str>) -> PyResult<Config> {
        match toml_text {
            Some(t) => Config::from_toml(t),
            None => Err(PyTypeError::new_err(
                "use Config.load(path), Config.from_toml(text) or Config.from_dict(d)",
            )),
        }
    }
}

/// Every registered numeric parameter: list of (path, unit, kind, range text, description).
#[pyfunction]
pub fn param_table() -> Vec<(String, String, String, String, String)> {
    registries()
        .iter()
        .flat_map(|t| t.iter())
        .map(|p| {
            (
                p.path.to_string(),
                p.unit.to_string(),
                match p.kind {
                    Kind::Float => "float",
                    Kind::Integer => "int",
                    Kind::FloatArray => "float[]",
                    Kind::Bool => "bool",
                    Kind::Choice(_) => "choice",
                }
                .to_string(),
                p.range.describe(),
                p.description.to_string(),
            )
        })
        .collect()
}
