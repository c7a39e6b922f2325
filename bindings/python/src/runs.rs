//! Closed-loop runs: one (`run_one`) or a batch in parallel on a rayon pool (`run_batch`).
//! Both call `ehactl_runtime::session::run_sim` — the exact code behind `ehactl run` —
//! with the GIL released. The calling thread only wakes up to forward progress to a Python
//! callback and to notice Ctrl-C (which stops the runs through the session's stop flag).

use crate::columns::{self, ColumnSink, Columns, COLUMNS, STUCK};
use crate::config::Config;
use ehactl_config::RigConfig;
use ehactl_log::record::CycleRecord;
use ehactl_runtime::session::{run_sim, SessionOptions};
use numpy::IntoPyArray;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;

/// Outcome of one run before conversion to Python objects.
struct RunOut {
    cols: Columns,
    summary: String,
}

fn check_duration(d: Option<f64>) -> PyResult<()> {
    match d {
        Some(x) if !(x.is_finite() && x > 0.0) => Err(PyValueError::new_err(format!(
            "duration = {x} is not valid; expected a finite number > 0 in s"
        ))),
        _ => Ok(()),
    }
}

fn one(
    cfg: &RigConfig,
    duration: Option<f64>,
    mcap: Option<PathBuf>,
    idx: &[usize],
    stuck: bool,
    stop: &AtomicBool,
    progress: Option<&AtomicU64>,
) -> Result<RunOut, String> {
    let mut report = |k: u64, _total: u64| {
        if let Some(p) = progress {
            p.store(k, Ordering::Relaxed);
        }
    };
    let cycles = (duration.unwrap_or(cfg.run.duration) / cfg.timebase().period())
        .round()
        .max(1.0) as usize;
    let mut sink = ColumnSink::new(idx, stuck, cycles);
    let mut observe = |r: &CycleRecord| sink.push(r);
    let session = run_sim(
        cfg,
        SessionOptions {
            duration,
            mcap,
            stop: Some(stop),
            capture: false,
            progress: Some(&mut report),
            observer: Some(&mut observe),
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())?;
    Ok(RunOut {
        cols: sink.finish(),
        summary: session.summary_json().to_string(),
    })
}

/// Run `work` on a scoped thread with the GIL released; meanwhile forward
/// `counter` to `progress(done, total)` (`total` may grow while `work` runs) and turn Ctrl-C
/// into `stop`.
pub(crate) fn detached<R: Send>(
    py: Python<'_>,
    progress: Option<Py<PyAny>>,
    total: &AtomicU64,
    counter: &AtomicU64,
    stop: &AtomicBool,
    work: impl FnOnce() -> R + Send,
) -> PyResult<R> {
    let mut py_err: Option<PyErr> = None;
    let out = py.detach(|| {
        std::thread::scope(|s| {
            let (tx, rx) = mpsc::channel::<()>();
            let h = s.spawn(move || {
                let r = work();
                let _ = tx.send(());
                r
            });
            let mut last = (u64::MAX, u64::MAX);
            let mut tick = |final_call: bool| {
                Python::attach(|py| {
                    if py_err.is_none() {
                        if let Err(e) = py.check_signals() {
                            stop.store(true, Ordering::Relaxed);
                            py_err = Some(e);
                        }
                    }
                    if let (Some(cb), None) = (&progress, &py_err) {
                        let n = counter.load(Ordering::Relaxed);
                        let m = total.load(Ordering::Relaxed);
                        if (n, m) != last || final_call {
                            last = (n, m);
                            if let Err(e) = cb.bind(py).call1((n, m)) {
                                stop.store(true, Ordering::Relaxed);
                                py_err = Some(e);
                            }
                        }
                    }
                })
            };
            loop {
                match rx.recv_timeout(Duration::from_millis(50)) {
                    Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    Err(mpsc::RecvTimeoutError::Timeout) => tick(false),
                }
            }
            let r = h.join();
            if progress.is_some() {
                tick(true);
            }
            r
        })
    });
    if let Some(e) = py_err {
        return Err(e);
    }
    out.map_err(|_| PyRuntimeError::new_err("ehactl simulation thread panicked"))
}

fn to_py<'py>(py: Python<'py>, r: RunOut) -> PyResult<(Bound<'py, PyDict>, String)> {
    let d = PyDict::new(py);
    d.set_item("cycle", r.cols.cycle.into_pyarray(py))?;
    for (name, v) in r.cols.floats {
        d.set_item(name, v.into_pyarray(py))?;
    }
    if let Some(s) = r.cols.stuck {
        d.set_item(STUCK, s.into_pyarray(py))?;
    }
    Ok((d, r.summary))
}

/// One closed-loop run of `cfg` (GIL released). Returns (dict of NumPy columns, summary
/// JSON text). `duration` (s) overrides run.duration; `mcap` writes the log there;
/// `fields` selects columns (None = all); `progress(done_cycles, total_cycles)` is
/// called from the calling thread about every 50 ms.
#[pyfunction]
#[pyo3(signature = (cfg, duration = None, mcap = None, fields = None, progress = None))]
pub fn run_one<'py>(
    py: Python<'py>,
    cfg: &Config,
    duration: Option<f64>,
    mcap: Option<PathBuf>,
    fields: Option<Vec<String>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(Bound<'py, PyDict>, String)> {
    check_duration(duration)?;
    let (idx, stuck) = columns::select(fields.as_deref()).map_err(PyValueError::new_err)?;
    let rc = cfg.cfg.clone();
    let total = AtomicU64::new(
        (duration.unwrap_or(rc.run.duration) / rc.timebase().period())
            .round()
            .max(1.0) as u64,
    );
    let counter = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let out = detached(py, progress, &total, &counter, &stop, || {
        one(&rc, duration, mcap, &idx, stuck, &stop, Some(&counter))
    })?;
    let r = out.map_err(PyValueError::new_err)?;
    to_py(py, r)
}

/// Many closed-loop runs in parallel on a rayon pool of `threads` workers (None = one per
/// core), GIL released. Same arguments as `run_one`, per run: `mcap` is None or a list of
/// paths, one per config. `progress(done_runs, total_runs)`. Returns a list of
/// (columns, summary JSON) in input order.
#[pyfunction]
#[pyo3(signature = (cfgs, duration = None, mcap = None, fields = None, threads = None, progress = None))]
pub fn run_batch<'py>(
    py: Python<'py>,
    cfgs: Vec<Config>,
    duration: Option<f64>,
    mcap: Option<Vec<PathBuf>>,
    fields: Option<Vec<String>>,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Vec<(Bound<'py, PyDict>, String)>> {
    check_duration(duration)?;
    let (idx, stuck) = columns::select(fields.as_deref()).map_err(PyValueError::new_err)?;
    if let Some(m) = &mcap {
        if m.len() != cfgs.len() {
            return Err(PyValueError::new_err(format!(
                "mcap: got {} paths for {} configs; expected one path per config",
                m.len(),
                cfgs.len()
            )));
        }
    }
    if threads == Some(0) {
        return Err(PyValueError::new_err(
            "threads = 0 is not valid; expected None (one per core) or ≥ 1",
        ));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start the thread pool: {e}")))?;
    let jobs: Vec<(RigConfig, Option<PathBuf>)> = cfgs
        .into_iter()
        .enumerate()
        .map(|(i, c)| (c.cfg, mcap.as_ref().map(|m| m[i].clone())))
        .collect();
    let total = AtomicU64::new(jobs.len() as u64);
    let counter = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let outs = detached(py, progress, &total, &counter, &stop, || {
        pool.install(|| {
            jobs.into_par_iter()
                .map(|(c, m)| {
                    let r = one(&c, duration, m, &idx, stuck, &stop, None);
                    counter.fetch_add(1, Ordering::Relaxed);
                    r
                })
                .collect::<Vec<_>>()
        })
    })?;
    let mut res = Vec::with_capacity(outs.len());
    for (i, o) in outs.into_iter().enumerate() {
        let r = o.map_err(|e| PyValueError::new_err(format!("run {i}: {e}")))?;
        res.push(to_py(py, r)?);
    }
    Ok(res)
}

/// (name, unit) of every float result column, in order (plus `cycle` and `stuck`).
#[pyfunction]
pub fn record_fields() -> Vec<(&'static str, &'static str)> {
    COLUMNS.iter().map(|c| (c.0, c.1)).collect()
}
