//! `ehactl diagnose` for Python: the same `ehactl-ident` session as the CLI, the `--json`
//! object handed over as a JSON string (parsed into a dict by `ehactl._analysis`).

use crate::config::Config;
use crate::runs::detached;
use ehactl_ident::progress::{Progress, ProgressSink};
use ehactl_ident::session::{self, SessionError};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Diagnose the measured record `data` (CSV or ehactl MCAP) against the nominal `cfg`;
/// `validate` is a separate held-out record (default: the last 30 % of `data`), `out` a
/// directory for extended.toml, report.md and plots; `sensor_offsets` estimates a constant
/// zero error per measured channel for every model; `progress(done_fits, total_fits)` is
/// called on the calling thread as fits finish (the total grows with each search round).
/// Returns (json, notes). Bad data or config raise ValueError, an unwritable report OSError.
/// The GIL is released meanwhile.
#[pyfunction]
#[pyo3(signature = (cfg, data, validate = None, out = None, progress = None, sensor_offsets = false))]
pub fn diagnose_json(
    py: Python<'_>,
    cfg: &Config,
    data: PathBuf,
    validate: Option<PathBuf>,
    out: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
    sensor_offsets: bool,
) -> PyResult<(String, Vec<String>)> {
    let rc = cfg.cfg.clone();
    let label = cfg.source.clone().unwrap_or_else(|| rc.rig.name.clone());
    let done = Arc::new(AtomicU64::new(0));
    let total = Arc::new(AtomicU64::new(1));
    let sink = if progress.is_some() {
        let (d, t) = (done.clone(), total.clone());
        ProgressSink::new(move |p: &Progress| {
            t.store(p.total, Ordering::Relaxed);
            d.store(p.done, Ordering::Relaxed);
        })
    } else {
        ProgressSink::none()
    };
    // A diagnosis cannot be interrupted half-way: Ctrl-C is raised when it returns.
    let stop = AtomicBool::new(false);
    let run = detached(py, progress, &total, &done, &stop, || {
        session::run(
            &rc,
            &label,
            &data,
            validate.as_deref(),
            out.as_deref(),
            session::RunChoices {
                progress: sink,
                sensor_offsets,
                ..Default::default()
            },
        )
    })?;
    match run {
        Ok(r) => Ok((r.json.to_string(), r.notes)),
        Err(SessionError::Input(e)) => Err(PyValueError::new_err(e)),
        Err(SessionError::Io(e)) => Err(PyOSError::new_err(e)),
    }
}
