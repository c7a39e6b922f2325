//! `ehactl analyze` and `ehactl sweep` for Python: the same `ehactl-analysis` code, results
//! handed over as the CLI's JSON (parsed into dicts / NumPy arrays by `ehactl._analysis`).

use crate::config::Config;
use crate::runs::detached;
use ehactl_analysis::sweep::{Channel, SweepOptions};
use ehactl_analysis::{analyze, sweep, AnalysisError};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

fn to_py(e: AnalysisError) -> PyErr {
    match e {
        AnalysisError::Config(e) => PyValueError::new_err(e.to_string()),
        AnalysisError::Session(ehactl_runtime::session::SessionError::Config(e)) => {
            PyValueError::new_err(e.to_string())
        }
        e => PyRuntimeError::new_err(e.to_string()),
    }
}

/// Linearise `cfg` around its operating point and return the `ehactl analyze --json` object
/// as a JSON string (margins of the sampled loop, continuous loop, bandwidths, poles, loop
/// response). The GIL is released while Rust works.
#[pyfunction]
pub fn analyze_json(py: Python<'_>, cfg: &Config) -> PyResult<String> {
    let rc = cfg.cfg.clone();
    py.detach(|| analyze(&rc).map(|a| a.to_json().to_string()))
        .map_err(to_py)
}

/// Stepped-sine frequency response of the nonlinear plant (`ehactl sweep --json` as a JSON
/// string). `output` is force, position, p_a or p_b; `progress(done_cycles, total_cycles)`.
#[pyfunction]
#[pyo3(signature = (cfg, from_hz = None, to_hz = None, points = 30, amplitude = None,
    open_loop = false, output = None, periods = 6.0, mcap = None, progress = None))]
#[allow(clippy::too_many_arguments)]
pub fn sweep_json(
    py: Python<'_>,
    cfg: &Config,
    from_hz: Option<f64>,
    to_hz: Option<f64>,
    points: usize,
    amplitude: Option<f64>,
    open_loop: bool,
    output: Option<String>,
    periods: f64,
    mcap: Option<PathBuf>,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let output = match output.as_deref() {
        None => None,
        Some(s) => Some(Channel::parse(s).ok_or_else(|| {
            PyValueError::new_err(format!(
                "output = {s:?}: expected one of force (N), position (m), p_a (Pa), p_b (Pa)"
            ))
        })?),
    };
    let rc = cfg.cfg.clone();
    let plan = SweepOptions {
        from_hz,
        points,
        periods,
        ..Default::default()
    };
    let total = AtomicU64::new(
        (plan.planned_duration(&rc) / rc.timebase().period())
            .round()
            .max(1.0) as u64,
    );
    let counter = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let out = detached(py, progress, &total, &counter, &stop, || {
        let mut report = |k: u64, _n: u64| counter.store(k, Ordering::Relaxed);
        sweep(
            &rc,
            SweepOptions {
                from_hz,
                to_hz,
                points,
                amplitude,
                open_loop,
                output,
                periods,
                mcap,
                stop: Some(&stop),
                progress: Some(&mut report),
                ..Default::default()
            },
        )
    })?;
    let r = out.map_err(to_py)?;
    serde_json::to_string(&r).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}
