//! Campaign diagnosis and `ehactl predict` for Python: the same `ehactl-ident` sessions as the
//! CLI, the `--json` objects handed over as JSON strings (parsed by `ehactl._campaign`).

use crate::config::Config;
use ehactl_ident::session::SessionError;
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use std::path::PathBuf;

fn to_py(e: SessionError) -> PyErr {
    match e {
        SessionError::Input(e) => PyValueError::new_err(e),
        SessionError::Io(e) => PyOSError::new_err(e),
    }
}

/// The config's file, if it was loaded from one (never written over by a report).
fn source(cfg: &Config) -> PathBuf {
    cfg.source.clone().map(PathBuf::from).unwrap_or_default()
}

/// `ehactl diagnose --data D1 --data D2 … [--validate V …] --json` of `cfg`: one load law for
/// every record (see `ehactl.diagnose`). The GIL is released meanwhile.
#[pyfunction]
#[pyo3(signature = (cfg, data, validate = Vec::new(), out = None, force = false))]
pub fn campaign_json(
    py: Python<'_>,
    cfg: &Config,
    data: Vec<PathBuf>,
    validate: Vec<PathBuf>,
    out: Option<PathBuf>,
    force: bool,
) -> PyResult<String> {
    let rc = cfg.cfg.clone();
    let src = source(cfg);
    py.detach(|| {
        ehactl_ident::campaign_run::run(&rc, &src, &data, &validate, out.as_deref(), force, false)
    })
    .map(|r| r.json.to_string())
    .map_err(to_py)
}

/// `ehactl predict --json` of `data` through the model `cfg` (see `ehactl.predict`).
#[pyfunction]
#[pyo3(signature = (cfg, data, imposed_motion = false, held_out = false, out = None, force = false))]
pub fn predict_json(
    py: Python<'_>,
    cfg: &Config,
    data: Vec<PathBuf>,
    imposed_motion: bool,
    held_out: bool,
    out: Option<PathBuf>,
    force: bool,
) -> PyResult<String> {
    let rc = cfg.cfg.clone();
    let src = source(cfg);
    py.detach(|| {
        ehactl_ident::predict::run(
            &rc,
            &src,
            &data,
            imposed_motion,
            held_out,
            out.as_deref(),
            force,
        )
    })
    .map(|r| r.json.to_string())
    .map_err(to_py)
}
