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
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;

/// Outcome of one run before conversion to Python objects.
struct RunOut {
    cols: Columns,
    summary: String,
}

/// Largest result arrays one call returns (bytes, all runs of a batch together): 2 000 MB.
/// With every column (31 float columns, `cycle`, `stuck`: 257 bytes per cycle) that is
/// 7.8·10⁶ cycles, 1 556 s at 5 kHz; `fields=` selects fewer columns for longer runs, and
/// the MCAP log (`mcap=`) has no such limit.
const MAX_RESULT_BYTES: u64 = 2_000_000_000;

/// Bytes of result arrays per cycle for the selected columns: 8 per float column, 8 for
/// `cycle`, 1 for `stuck`.
fn bytes_per_cycle(idx: &[usize], stuck: bool) -> u64 {
    8 * idx.len() as u64 + 8 + u64::from(stuck)
}

/// Check a duration override (s) against the range of `run.duration`.
fn check_duration(d: Option<f64>) -> PyResult<()> {
    match d.map(ehactl_runtime::session::check_duration) {
        Some(Err(why)) => Err(PyValueError::new_err(format!("duration = {why}"))),
        _ => Ok(()),
    }
}

/// Cycles a run of `cfg` takes (the duration override or `run.duration`).
fn cycles_of(cfg: &RigConfig, duration: Option<f64>) -> u64 {
    cfg.timebase()
        .cycles_in(duration.unwrap_or(cfg.run.duration))
        .max(1)
}

/// Refuse runs whose result arrays would exceed [`MAX_RESULT_BYTES`] before anything is
/// allocated (a ValueError naming the limit, instead of an allocation failure that aborts
/// the interpreter).
fn check_result_size(cycles: &[u64], idx: &[usize], stuck: bool) -> PyResult<()> {
    let per = bytes_per_cycle(idx, stuck);
    let total: u64 = cycles
        .iter()
        .map(|c| c.saturating_mul(per))
        .fold(0, u64::saturating_add);
    if total > MAX_RESULT_BYTES {
        let n: u64 = cycles.iter().sum();
        return Err(PyValueError::new_err(format!(
            "duration: {n} cycles × {per} bytes of result columns = {:.1} MB exceeds the limit of {} MB for the arrays returned to Python; expected a shorter duration, fewer columns (fields=[…]) or fewer runs (the MCAP log, mcap=, has no such limit)",
            total as f64 / 1e6,
            MAX_RESULT_BYTES / 1_000_000
        )));
    }
    Ok(())
}

/// Refuse an MCAP path that would destroy a file of the user's (the rules of `ehactl run
/// --out`, `ehactl_log::outpath`): never the config, never a directory, never an existing
/// file that is not an MCAP log unless `overwrite`.
fn check_mcap_path(path: &Path, cfg: &Config, overwrite: bool) -> PyResult<()> {
    use ehactl_log::outpath::{check_log_path, LogPathError, Naming};
    let source = cfg.source.as_deref().map(Path::new);
    let inputs: Vec<&Path> = source.into_iter().collect();
    let naming = Naming {
        arg: "mcap",
        force_hint: "pass overwrite=True",
    };
    check_log_path(path, &inputs, overwrite, naming).map_err(|e| match e {
        LogPathError::Refused(m) => PyValueError::new_err(m),
        LogPathError::Busy(m) => PyOSError::new_err(m),
    })
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
    let cycles = usize::try_from(cycles_of(cfg, duration)).map_err(|e| e.to_string())?;
    let mut sink = ColumnSink::new(idx, stuck, cycles);
    let mut observe = |r: &CycleRecord| sink.push(r);
    let session = run_sim(
        cfg,
        SessionOptions {
            duration,
            mcap,
            atomic_log: true,
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
/// JSON text). `duration` (s) overrides run.duration; `mcap` writes the log there
/// (written under a temporary name and renamed when complete; an existing file that is not
/// an MCAP log only with `overwrite`, the config never); `fields` selects columns (None =
/// all); `progress(done_cycles, total_cycles)` is called from the calling thread about
/// every 50 ms.
#[pyfunction]
#[pyo3(signature = (cfg, duration = None, mcap = None, fields = None, progress = None, overwrite = false))]
pub fn run_one<'py>(
    py: Python<'py>,
    cfg: &Config,
    duration: Option<f64>,
    mcap: Option<PathBuf>,
    fields: Option<Vec<String>>,
    progress: Option<Py<PyAny>>,
    overwrite: bool,
) -> PyResult<(Bound<'py, PyDict>, String)> {
    check_duration(duration)?;
    let (idx, stuck) = columns::select(fields.as_deref()).map_err(PyValueError::new_err)?;
    let rc = cfg.cfg.clone();
    let cycles = cycles_of(&rc, duration);
    check_result_size(&[cycles], &idx, stuck)?;
    if let Some(m) = &mcap {
        check_mcap_path(m, cfg, overwrite)?;
    }
    let total = AtomicU64::new(cycles);
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
/// paths, one per config (distinct; checked as `run_one`'s, with `overwrite`).
/// `progress(done_runs, total_runs)`. Returns a list of (columns, summary JSON) in input
/// order.
#[pyfunction]
#[pyo3(signature = (cfgs, duration = None, mcap = None, fields = None, threads = None, progress = None, overwrite = false))]
#[allow(clippy::too_many_arguments)]
pub fn run_batch<'py>(
    py: Python<'py>,
    cfgs: Vec<Config>,
    duration: Option<f64>,
    mcap: Option<Vec<PathBuf>>,
    fields: Option<Vec<String>>,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    overwrite: bool,
) -> PyResult<Vec<(Bound<'py, PyDict>, String)>> {
    check_duration(duration)?;
    let (idx, stuck) = columns::select(fields.as_deref()).map_err(PyValueError::new_err)?;
    let cycles: Vec<u64> = cfgs.iter().map(|c| cycles_of(&c.cfg, duration)).collect();
    check_result_size(&cycles, &idx, stuck)?;
    if let Some(m) = &mcap {
        if m.len() != cfgs.len() {
            return Err(PyValueError::new_err(format!(
                "mcap: got {} paths for {} configs; expected one path per config",
                m.len(),
                cfgs.len()
            )));
        }
        for (i, (p, c)) in m.iter().zip(&cfgs).enumerate() {
            // The message names the path, which names the run.
            if m[..i].contains(p) {
                return Err(PyValueError::new_err(format!(
                    "mcap {}: given for two runs; expected one distinct path per run",
                    p.display()
                )));
            }
            check_mcap_path(p, c, overwrite)?;
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
