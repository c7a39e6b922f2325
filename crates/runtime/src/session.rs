//! One complete run: configure the plant, build the controller, supervisor and setpoint,
//! bring the backend up, run the loop (in simulated time, [`run_sim`], or paced by the wall
//! clock against the simulated plant or a rig, [`run_realtime`]), log every cycle to MCAP
//! and summarise. Shared by the CLI and the Python bindings so both run exactly the same
//! code: the one composition root of sim and CAN runs.
//!
//! Every backend goes through the [`Hal`] lifecycle here ([`run_with_live`]): configure,
//! activate, the loop's read / write, and the loop's deactivate or safe stop at the end. The
//! simulated plant keeps the trait's defaults (nothing to bring up); a CAN rig arrives
//! unconfigured and is brought up here, where a failed start-up is logged like a trip: the
//! MCAP holds `/config`, the frames of the attempt on `/can`, one event and a `/summary` with
//! the reason (`trip_kind` `startup`; see [`SessionError::Startup`]).

use crate::live::LiveParams;
use crate::realtime::{RtOptions, WallClockPacer};
use crate::runloop::{run_loop, LoopSettings, RunOutcome};
use crate::sim::SimHal;
use ehactl_config::{Compression, RigConfig};
use ehactl_control::controller::Controller;
use ehactl_control::setpoint::Setpoint;
use ehactl_control::supervisor::Supervisor;
use ehactl_hal::pacer::{Pacer, SimulatedTime, TimingReport};
use ehactl_hal::{Hal, StartupReport};
use ehactl_log::logger::{
    FrameLog, LogCompression, LogOptions, LogStats, Logger, Overflow, RunMetadata,
};
use ehactl_log::record::{CycleRecord, Event, EventKind, Severity};
use ehactl_plant::{ConfigError, Plant};
use serde_json::json;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

/// Exit code of `ehactl run` when the hardware could not be brought up, as recorded in the
/// summary of a failed start-up (`exit_code`).
pub const EXIT_STARTUP: u8 = 4;

/// Exit code of `ehactl run` stopped by SIGINT / SIGTERM (also during start-up), as recorded
/// in the summary of a start-up cut short by a signal.
pub const EXIT_STOPPED: u8 = 130;

/// Options of a run beyond the config.
#[derive(Default)]
pub struct SessionOptions<'a> {
    /// Override of `run.duration` (s).
    pub duration: Option<f64>,
    /// MCAP output path; None = no log.
    pub mcap: Option<PathBuf>,
    /// Write the log under a temporary name beside `mcap` and rename it to `mcap` only once
    /// it is complete (footer written): the path then holds either what was there before or
    /// a whole log, never a half-written one. A run that fails removes its temporary file.
    /// (The CLI does not: a killed run's log must stay under the name the user gave, for
    /// `ehactl recover`.)
    pub atomic_log: bool,
    /// Stop flag (signal handler).
    pub stop: Option<&'a AtomicBool>,
    /// Keep every cycle record in memory (for the Python bindings).
    pub capture: bool,
    /// Progress callback: (cycles done, cycles total).
    pub progress: Option<&'a mut dyn FnMut(u64, u64)>,
    /// Sees every cycle record as it is produced (streaming estimators, e.g. `ehactl sweep`).
    pub observer: Option<&'a mut dyn FnMut(&CycleRecord)>,
    /// Log one cycle in `log_every` to the MCAP file (0 or 1: every cycle); events, the
    /// first and the last cycle are always logged. Observers and captures see every cycle.
    pub log_every: u64,
    /// Also hand everything logged to this tap (live view, `ehactl run --live`).
    pub tap: Option<std::sync::Arc<ehactl_log::logger::LogTap>>,
    /// The bus address as the user gave it (`ehactl run --bus`), the `bus` of the summary
    /// of a failed hardware start-up.
    pub bus: Option<String>,
    /// Events found before the run (e.g. `unstable_loop`: the config's linearised loop is
    /// unstable), logged on `/events` right after the run's `start` event.
    pub start_events: Vec<Event>,
}

/// Result of a run.
#[derive(Debug, Clone)]
pub struct Session {
    /// Loop outcome.
    pub outcome: RunOutcome,
    /// Control rate (Hz).
    pub control_rate_hz: f64,
    /// Wall-clock time of the loop (s).
    pub wall_time_s: f64,
    /// Plant substeps per control period.
    pub substeps: u32,
    /// Log counters, if logged.
    pub log: Option<LogStats>,
    /// Captured records (if requested).
    pub records: Vec<CycleRecord>,
    /// Unit of the controlled variable.
    pub unit: &'static str,
    /// Backend-specific summary fields ([`Hal::report`]), merged into the summary.
    pub backend_report: Option<serde_json::Value>,
    /// Wall-clock timing statistics (wall-clock pacers only).
    pub timing: Option<TimingReport>,
    /// One cycle in `log_every` was logged.
    pub log_every: u64,
}

/// Why a run could not start or its log could not be written.
#[derive(Debug)]
pub enum SessionError {
    /// Bad config.
    Config(ConfigError),
    /// Log file problem.
    Log(ehactl_log::logger::LogError),
    /// The backend's configure or activate failed; the loop never ran.
    Startup(Box<FailedStartup>),
}

/// A backend start-up that failed ([`Hal::configure`] / [`Hal::activate`]), and what became
/// of its log.
#[derive(Debug)]
pub struct FailedStartup {
    /// Why, with the frames of the attempt ([`Hal::take_startup_report`]).
    pub report: StartupReport,
    /// The summary written to the MCAP of the attempt (with `records_written`); `Ok(None)`
    /// when nothing was logged (no `mcap` path, or a settings error: nothing reached the
    /// hardware); `Err` with the reason when the log could not be written.
    pub log: Result<Option<serde_json::Value>, String>,
}

impl std::fmt::Display for SessionError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SessionError::Config(e) => e.fmt(f),
            SessionError::Log(e) => e.fmt(f),
            SessionError::Startup(s) => f.write_str(&s.report.reason),
        }
    }
}

impl std::error::Error for SessionError {}

impl Session {
    /// Summary as one JSON object (the `ehactl run --json` output).
    pub fn summary_json(&self) -> serde_json::Value {
        let o = &self.outcome;
        let num = |v: f64| {
            if v.is_finite() {
                json!(v)
            } else {
                serde_json::Value::Null
            }
        };
        let mut v = json!({
            "cycles": o.cycles,
            "control_rate_hz": self.control_rate_hz,
            "duration_s": o.duration_s,
            "rms_error": num(o.rms_error),
            "rms_error_settled": num(o.rms_error_settled),
            "max_abs_error": num(o.max_abs_error),
            "error_unit": self.unit,
            "mcap": self.log.as_ref().map(|l| l.path.display().to_string()),
            "trip": o.trip.map(|e| e.describe()),
            "trip_kind": o.trip.map(|e| e.kind.as_str()),
            "interrupted": o.interrupted,
            "sim_speed_x_realtime": if self.wall_time_s > 0.0 { o.duration_s / self.wall_time_s } else { 0.0 },
            "wall_time_s": self.wall_time_s,
            "substeps": self.substeps,
            "log_decimation": self.log_every,
            "log": self.log.as_ref().map(|l| json!({
                "records_written": l.records_written,
                "records_dropped": l.records_dropped,
                "pushes_waited": l.pushes_waited,
                "events_written": l.events_written,
                "queue_high_water": l.queue_high_water,
                "queue_capacity": l.queue_capacity,
                "can_frames_written": l.frames_written,
                "can_frames_dropped": l.frames_dropped,
            })),
            "realtime": self.timing.is_some(),
        });
        if let Some(tm) = &self.timing {
            let obj = v.as_object_mut().expect("object");
            let put = |o: &mut serde_json::Map<String, serde_json::Value>, k: &str, x: f64| {
                o.insert(k.into(), num(x));
            };
            for (name, q) in [
                ("jitter", &tm.jitter),
                ("period", &tm.period),
                ("exec", &tm.exec),
                ("exec_cpu", &tm.exec_cpu),
            ] {
                put(obj, &format!("{name}_p50_us"), q.p50);
                put(obj, &format!("{name}_p99_us"), q.p99);
                put(obj, &format!("{name}_p999_us"), q.p999);
                put(obj, &format!("{name}_max_us"), q.max);
            }
            put(obj, "period_min_us", tm.period.min);
            obj.insert("exec_cpu_clamped".into(), json!(tm.exec_cpu_clamped));
            obj.insert("overruns".into(), json!(tm.overruns));
            // The split of `overruns`: our execution vs a late start (DEPLOY.md §8).
            obj.insert("overruns_exec".into(), json!(tm.overruns_exec));
            obj.insert("overruns_wakeup".into(), json!(tm.overruns_wakeup));
            obj.insert(
                "longest_overrun_streak".into(),
                json!(tm.longest_overrun_streak),
            );
            obj.insert("skipped_deadlines".into(), json!(tm.skipped_deadlines));
            obj.insert(
                "log_queue_high_water".into(),
                json!(self.log.as_ref().map(|l| l.queue_high_water)),
            );
            obj.insert(
                "timing".into(),
                serde_json::to_value(tm).unwrap_or(serde_json::Value::Null),
            );
        }
        if let (Some(obj), Some(serde_json::Value::Object(extra))) =
            (v.as_object_mut(), self.backend_report.as_ref())
        {
            for (k, x) in extra {
                obj.insert(k.clone(), x.clone());
            }
        }
        v
    }
}

/// Configure the plant for a config.
pub fn build_plant(cfg: &RigConfig) -> Result<Plant, ConfigError> {
    Plant::configure(&cfg.plant, cfg.timebase().period())
}

/// Run `cfg` against the simulated plant in simulated time.
pub fn run_sim(cfg: &RigConfig, opts: SessionOptions<'_>) -> Result<Session, SessionError> {
    run_sim_live(cfg, opts, None)
}

/// [`run_sim`] with gains and setpoint changeable while it runs (`live`, swapped at cycle
/// boundaries; see [`crate::live`]).
pub fn run_sim_live(
    cfg: &RigConfig,
    opts: SessionOptions<'_>,
    live: Option<&LiveParams>,
) -> Result<Session, SessionError> {
    let mut cfg_run = cfg.clone();
    if let Some(d) = opts.duration {
        cfg_run.run.duration = d;
    }
    let plant = build_plant(&cfg_run).map_err(SessionError::Config)?;
    let substeps = plant.substeps();
    let mut hal = SimHal::new(plant);
    let backend = Backend {
        hal: &mut hal,
        pacer: &mut SimulatedTime,
        overflow: Overflow::Block,
        substeps,
    };
    run_with_live(cfg, backend, opts, live)
}

/// Run `cfg` paced by the wall clock ([`WallClockPacer`] with the config's `[realtime]`
/// settings; `warn` receives the set-up warnings): against `hardware` (a CAN rig, handed
/// over unconfigured: [`run_with_live`] brings it up) or, without it, against the simulated
/// plant in real time (hardware-in-the-loop rehearsal). The logger drops and counts rather
/// than waits, so the loop never blocks on the disk. The one composition of a paced run, for
/// `ehactl run --realtime` and CAN runs.
pub fn run_realtime(
    cfg: &RigConfig,
    opts: SessionOptions<'_>,
    live: Option<&LiveParams>,
    hardware: Option<&mut dyn Hal>,
    warn: Option<fn(&str)>,
) -> Result<Session, SessionError> {
    let mut cfg_run = cfg.clone();
    if let Some(d) = opts.duration {
        cfg_run.run.duration = d;
    }
    // The plant is configured with hardware too: a plant section the plant refuses fails
    // the run the same way with or without a rig.
    let plant = build_plant(&cfg_run).map_err(SessionError::Config)?;
    let mut sim;
    let (hal, substeps): (&mut dyn Hal, u32) = match hardware {
        Some(h) => (h, 0),
        None => {
            let substeps = plant.substeps();
            sim = SimHal::new(plant);
            (&mut sim, substeps)
        }
    };
    let mut rt = RtOptions::from_config(&cfg.realtime);
    rt.warn = warn;
    let mut pacer = WallClockPacer::new(cfg.timebase(), rt);
    let backend = Backend {
        hal,
        pacer: &mut pacer,
        overflow: Overflow::Drop,
        substeps,
    };
    run_with_live(cfg, backend, opts, live)
}

/// Check a run duration `d` (s): finite, > 0 and at most
/// [`ehactl_config::MAX_DURATION_S`] (the range of `run.duration`). The reason, with unit,
/// when not.
pub fn check_duration(d: f64) -> Result<(), String> {
    let max = ehactl_config::MAX_DURATION_S;
    if d.is_finite() && d > 0.0 && d <= max {
        Ok(())
    } else {
        Err(format!(
            "{d} s is not a valid duration; expected a finite number > 0 and at most {max:e} s (the range of run.duration)"
        ))
    }
}

/// The temporary name an atomic log is written under: `.<name>.partial-<pid>-<n>` in the
/// same directory (a rename within one file system is atomic).
fn partial_path(path: &std::path::Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map_or("log.mcap".into(), |n| n.to_string_lossy().into_owned());
    let n = N.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.partial-{}-{n}", std::process::id()))
}

/// The hardware side of a session: which `Hal`, how cycles are paced, and what the logger
/// does when its queue is full (block in simulated time, drop against the wall clock).
pub struct Backend<'a> {
    /// Hardware interface (simulated plant or devices).
    pub hal: &'a mut dyn Hal,
    /// Cycle pacing (simulated time or a wall-clock executor).
    pub pacer: &'a mut dyn Pacer,
    /// Logger overflow policy.
    pub overflow: Overflow,
    /// Plant substeps per control period (0 when the plant is real hardware).
    pub substeps: u32,
}

/// Create the MCAP log of a run of `cfg` on `backend` at `path`: the config's `[log]`
/// compression and queue capacity, the config as metadata. The one place a log is opened,
/// for runs and for a hardware start-up that failed before the run.
pub fn open_log(
    cfg: &RigConfig,
    path: &std::path::Path,
    backend: &str,
    overflow: Overflow,
) -> Result<Logger, ehactl_log::logger::LogError> {
    Logger::create(
        path,
        LogOptions {
            compression: match cfg.log.compression {
                Compression::None => LogCompression::None,
                Compression::Lz4 => LogCompression::Lz4,
            },
            queue_capacity: cfg.log.queue_capacity as usize,
            overflow,
            chunk_interval: cfg.log.chunk_interval,
            max_lag: (cfg.log.chunk_interval * cfg.run.control_rate_hz).ceil() as usize,
        },
        &RunMetadata {
            config_toml: cfg.to_toml_string(),
            config_json: cfg.to_json(),
            backend: backend.into(),
            control_rate_hz: cfg.run.control_rate_hz,
            config_schema: config_json_schema(),
        },
    )
}

/// Bring `hal` up: [`Hal::configure`] then [`Hal::activate`] (nothing to do for the
/// simulated plant). On failure the attempt is logged to `opts.mcap` (unless the settings
/// were wrong, then nothing reached the hardware) by [`log_failed_startup`] with `cfg`, the
/// config as given (without a `duration` override: the loop never ran).
fn start_up(
    cfg: &RigConfig,
    hal: &mut dyn Hal,
    opts: &SessionOptions<'_>,
) -> Result<(), SessionError> {
    let Err(e) = hal.configure().and_then(|()| hal.activate()) else {
        return Ok(());
    };
    // A backend without a report (a lifecycle error): the error itself, no frames.
    let report = hal.take_startup_report().unwrap_or_else(|| StartupReport {
        reason: e.to_string(),
        channel: "start-up",
        settings_error: false,
        stopped: false,
        elapsed_s: 0.0,
        time_limit_s: None,
        frames: Vec::new(),
    });
    let log = match (&opts.mcap, report.settings_error) {
        (Some(path), false) => {
            // With `atomic_log` under the temporary name first, as a run's log.
            let partial = opts.atomic_log.then(|| partial_path(path));
            let target = partial.as_deref().unwrap_or(path);
            let mut r = log_failed_startup(cfg, target, path, hal.name(), opts, &report);
            if let (Ok(_), Some(tmp)) = (&r, &partial) {
                if let Err(e) = std::fs::rename(tmp, path) {
                    r = Err(format!("cannot move the finished log into place: {e}"));
                }
            }
            if let (Err(_), Some(tmp)) = (&r, &partial) {
                let _ = std::fs::remove_file(tmp);
            }
            r.map(Some)
        }
        _ => Ok(None),
    };
    Err(SessionError::Startup(Box::new(FailedStartup {
        report,
        log,
    })))
}

/// Write the MCAP of a failed start-up at `target` (named `path` in the summary): `/config`,
/// `/can` (every frame of the attempt, times <= 0 up to the failure), one `hal_fault` trip on
/// `/events`, and `/summary` with the reason (`trip`, `trip_kind` = `startup`); returns the
/// summary. A start-up stopped by a signal is logged as interrupted instead: an info
/// `signal` event, `trip` null, `interrupted` true, the reason in `startup_stopped`,
/// `exit_code` 130.
fn log_failed_startup(
    cfg: &RigConfig,
    target: &std::path::Path,
    path: &std::path::Path,
    backend: &'static str,
    opts: &SessionOptions<'_>,
    f: &StartupReport,
) -> Result<serde_json::Value, String> {
    let logger = open_log(cfg, target, backend, Overflow::Block).map_err(|e| e.to_string())?;
    let frames = Arc::new(FrameLog::new(f.frames.len().max(1)));
    for r in &f.frames {
        frames.push(*r);
    }
    logger.attach_frames(frames);
    let stopped = f.stopped;
    logger.event(Event {
        t: 0.0,
        cycle: 0,
        severity: if stopped {
            Severity::Info
        } else {
            Severity::Trip
        },
        kind: if stopped {
            EventKind::Signal
        } else {
            EventKind::HalFault
        },
        channel: f.channel,
        value: f.elapsed_s,
        limit: f.time_limit_s.unwrap_or(f64::NAN),
        unit: "s",
    });
    let reason = f.reason.clone();
    let mut summary = serde_json::json!({
        "backend": backend,
        "bus": opts.bus,
        "cycles": 0,
        "duration_s": 0.0,
        "trip": if stopped { serde_json::Value::Null } else { reason.clone().into() },
        "trip_kind": if stopped { serde_json::Value::Null } else { "startup".into() },
        "interrupted": stopped,
        "startup_stopped": if stopped { reason.into() } else { serde_json::Value::Null },
        "startup_s": f.elapsed_s,
        "can_startup_frames": f.frames.len(),
        "exit_code": if stopped { EXIT_STOPPED } else { EXIT_STARTUP },
        "mcap": path.display().to_string(),
    });
    let stats = logger.finish(summary.clone()).map_err(|e| e.to_string())?;
    // What the logger added to the logged summary, so that both are the same.
    summary["records_written"] = stats.records_written.into();
    Ok(summary)
}

/// JSON Schema of a config as JSON ([`RigConfig::to_json`]), built from the parameter
/// registries: every registered field with its type, unit and meaning (the `/config` schema,
/// so that Foxglove lists the fields).
pub fn config_json_schema() -> serde_json::Value {
    use ehactl_plant::spec::Kind;
    let mut root = serde_json::Map::new();
    for table in ehactl_config::registries() {
        for p in table {
            let mut node = &mut root;
            let parts: Vec<&str> = p.path.split('.').collect();
            for part in &parts[..parts.len() - 1] {
                let entry = node
                    .entry(part.to_string())
                    .or_insert_with(|| json!({"type": "object", "properties": {}}));
                node = entry["properties"].as_object_mut().expect("object node");
            }
            let description = if p.unit == "-" || p.unit.is_empty() {
                p.description.to_string()
            } else {
                format!("{} ({})", p.description, p.unit)
            };
            let mut leaf = match p.kind {
                Kind::Float => json!({"type": "number"}),
                Kind::Integer => json!({"type": "integer"}),
                Kind::FloatArray => json!({"type": "array", "items": {"type": "number"}}),
                Kind::Bool => json!({"type": "boolean"}),
                Kind::Choice(c) => json!({"type": "string", "enum": c}),
            };
            leaf["description"] = json!(description);
            node.insert(parts[parts.len() - 1].to_string(), leaf);
        }
    }
    json!({"type": "object", "description": "rig config (SI units)", "properties": root})
}

/// Run `cfg` against any backend: the one loop shared by the simulated and the hardware
/// runs (the CLI, the Python bindings and the wall-clock executor all end up here).
pub fn run_with(
    cfg: &RigConfig,
    backend: Backend<'_>,
    opts: SessionOptions<'_>,
) -> Result<Session, SessionError> {
    run_with_live(cfg, backend, opts, None)
}

/// [`run_with`] with live gain / setpoint changes taken from `live` at cycle boundaries
/// (fed by the control socket, [`crate::control_socket`]). The backend is brought up here
/// ([`Hal::configure`], [`Hal::activate`]; may block, and ends early on `opts.stop`); a
/// failed start-up is logged and returned as [`SessionError::Startup`].
pub fn run_with_live(
    cfg: &RigConfig,
    backend: Backend<'_>,
    mut opts: SessionOptions<'_>,
    live: Option<&LiveParams>,
) -> Result<Session, SessionError> {
    let Backend {
        hal,
        pacer,
        overflow,
        substeps,
    } = backend;
    let duration = opts.duration.unwrap_or(cfg.run.duration);
    if let Err(why) = check_duration(duration) {
        return Err(SessionError::Config(ConfigError::new("--duration", why)));
    }
    start_up(cfg, hal, &opts)?;
    // The log records the config as run, including a duration override.
    let cfg = &config_as_run(cfg, opts.duration);
    let cycles = cfg.timebase().cycles_in(duration).max(1);
    let log = RunLog::open(cfg, &opts, hal, overflow, live)?;
    let (outcome, records, wall) = run_cycles(cfg, hal, pacer, &mut opts, live, cycles, &log);
    let timing = pacer.timing_report();
    let mut session = Session {
        outcome,
        control_rate_hz: cfg.run.control_rate_hz,
        wall_time_s: wall,
        substeps,
        log: None,
        records,
        unit: cfg.control.mode.unit(),
        backend_report: hal.report(),
        timing,
        log_every: opts.log_every.max(1),
    };
    session.log = log.finish(&session, opts.mcap.clone())?;
    Ok(session)
}

/// `cfg` with `run.duration` replaced by the override `duration` (s), if there is one.
fn config_as_run(cfg: &RigConfig, duration: Option<f64>) -> RigConfig {
    let mut cfg_run = cfg.clone();
    if let Some(d) = duration {
        cfg_run.run.duration = d;
    }
    cfg_run
}

/// The MCAP log of a run while it is written: none without an `mcap` path; with
/// `atomic_log` it is written under the temporary name `partial` and renamed at the end.
struct RunLog {
    logger: Option<Logger>,
    partial: Option<PathBuf>,
}

impl RunLog {
    /// Open the log of the run of `cfg` (the config as run) on `hal` as `opts` say, with
    /// the backend's CAN frames, the live notes and the tap attached.
    fn open(
        cfg: &RigConfig,
        opts: &SessionOptions<'_>,
        hal: &dyn Hal,
        overflow: Overflow,
        live: Option<&LiveParams>,
    ) -> Result<Self, SessionError> {
        // With `atomic_log` the file is written under `partial` and renamed at the end.
        let partial = opts
            .mcap
            .as_deref()
            .filter(|_| opts.atomic_log)
            .map(partial_path);
        let logger = match (&opts.mcap, &partial) {
            (_, Some(tmp)) => Some(open_log(cfg, tmp, hal.name(), overflow).map_err(|e| {
                let _ = std::fs::remove_file(tmp);
                SessionError::Log(e)
            })?),
            (Some(path), None) => {
                Some(open_log(cfg, path, hal.name(), overflow).map_err(SessionError::Log)?)
            }
            (None, None) => None,
        };
        if let (Some(l), Some(frames)) = (logger.as_ref(), hal.frame_log()) {
            l.attach_frames(frames);
        }
        if let (Some(l), Some(lp)) = (logger.as_ref(), live) {
            l.attach_notes(lp.notes());
        }
        if let (Some(l), Some(tap)) = (logger.as_ref(), opts.tap.clone()) {
            l.attach_tap(tap);
        }
        Ok(Self { logger, partial })
    }

    /// Write the summary of `session` (with `mcap`, the path the log ends up at), close the
    /// file and, with `atomic_log`, move it into place; a run that fails here removes its
    /// temporary file. Returns the log's counters (None when nothing was logged).
    fn finish(
        self,
        session: &Session,
        mcap: Option<PathBuf>,
    ) -> Result<Option<LogStats>, SessionError> {
        let Self { logger, partial } = self;
        let Some(l) = logger else {
            return Ok(None);
        };
        let final_path = mcap.unwrap_or_else(|| l.path().to_path_buf());
        let mut summary = session.summary_json();
        summary["mcap"] = serde_json::json!(final_path.display().to_string());
        let finished = l.finish(summary).map_err(SessionError::Log);
        let mut stats = match (finished, &partial) {
            (Ok(s), _) => s,
            (Err(e), Some(tmp)) => {
                let _ = std::fs::remove_file(tmp);
                return Err(e);
            }
            (Err(e), None) => return Err(e),
        };
        if let Some(tmp) = &partial {
            if let Err(e) = std::fs::rename(tmp, &final_path) {
                let _ = std::fs::remove_file(tmp);
                return Err(SessionError::Log(ehactl_log::logger::LogError {
                    path: final_path,
                    message: format!("cannot move the finished log into place: {e}"),
                    at_create: false,
                }));
            }
            stats.path = final_path;
        }
        Ok(Some(stats))
    }
}

/// The control side of a run, built from the config as run: the control law, the
/// supervisor and the setpoint generator.
struct ControlParts {
    controller: Controller,
    supervisor: Supervisor,
    setpoint: Setpoint,
}

impl ControlParts {
    fn new(cfg: &RigConfig) -> Self {
        let controller = cfg.controller();
        let supervisor = Supervisor::new(&cfg.supervisor_settings(), controller.feedback_channel());
        let setpoint = Setpoint::new(&cfg.setpoint);
        Self {
            controller,
            supervisor,
            setpoint,
        }
    }
}

/// Run the `cycles` control cycles of `cfg` (the config as run) on `hal`, paced by `pacer`.
/// Returns the outcome, the records kept with `opts.capture` (memory reserved for all
/// `cycles` before the loop starts) and the wall-clock time of the loop (s).
fn run_cycles(
    cfg: &RigConfig,
    hal: &mut dyn Hal,
    pacer: &mut dyn Pacer,
    opts: &mut SessionOptions<'_>,
    live: Option<&LiveParams>,
    cycles: u64,
    log: &RunLog,
) -> (RunOutcome, Vec<CycleRecord>, f64) {
    let mut parts = ControlParts::new(cfg);
    let mut records: Vec<CycleRecord> = if opts.capture {
        Vec::with_capacity(cycles as usize)
    } else {
        Vec::new()
    };
    let logger = log.logger.as_ref();
    let settings = LoopSettings {
        cycles,
        timebase: cfg.timebase(),
        stop: opts.stop,
        settle_time: parts.setpoint.dynamic_start(),
        live,
        log_failed: logger.map(|l| l.failed_flag()),
    };
    let start = Instant::now();
    let outcome = drive(
        hal,
        pacer,
        &mut parts,
        &settings,
        opts,
        logger,
        &mut records,
    );
    (outcome, records, start.elapsed().as_secs_f64())
}

/// The loop itself, with where each cycle goes: its record to the log (one in
/// `opts.log_every`, the last always), the observer and, with `opts.capture`, `records`
/// (reserved beforehand); its events to the log; progress every 1 % to `opts.progress`.
fn drive(
    hal: &mut dyn Hal,
    pacer: &mut dyn Pacer,
    parts: &mut ControlParts,
    settings: &LoopSettings<'_>,
    opts: &mut SessionOptions<'_>,
    lg: Option<&Logger>,
    records: &mut Vec<CycleRecord>,
) -> RunOutcome {
    let cycles = settings.cycles;
    let capture = opts.capture;
    let log_every = opts.log_every.max(1);
    let observer = &mut opts.observer;
    let mut on_record = |r: &CycleRecord| {
        if let Some(l) = lg {
            if r.cycle.is_multiple_of(log_every) || r.cycle + 1 >= cycles {
                l.push(r);
            }
        }
        if let Some(o) = observer.as_mut() {
            o(r);
        }
        if capture {
            records.push(*r);
        }
    };
    // Taken before the loop: handing them on allocates nothing in the cycle.
    let start_events = std::mem::take(&mut opts.start_events);
    let mut on_event = |e: Event| {
        if let Some(l) = lg {
            l.event(e);
            if e.kind == EventKind::Start {
                start_events.iter().for_each(|w| l.event(*w));
            }
        }
    };
    let mut on_progress = |k: u64| {
        if let Some(p) = opts.progress.as_mut() {
            p(k, cycles);
        }
    };
    run_loop(
        hal,
        &mut parts.controller,
        &parts.setpoint,
        &mut parts.supervisor,
        pacer,
        settings,
        &mut on_record,
        &mut on_event,
        &mut on_progress,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use ehactl_hal::pacer::SimulatedTime;
    use ehactl_hal::{CanFrameRecord, HalError, Measurements};

    fn boom() -> RigConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/dindorf2022_boom.toml");
        RigConfig::load(&path).expect("config loads")
    }

    /// A backend whose configure or activate fails with `report` (or succeeds), recording
    /// the lifecycle calls it gets.
    struct Scripted {
        fail_at: Option<&'static str>,
        report: Option<StartupReport>,
        calls: Vec<&'static str>,
    }

    impl Scripted {
        fn lifecycle(&mut self, call: &'static str) -> Result<(), HalError> {
            self.calls.push(call);
            if self.fail_at == Some(call) {
                Err(HalError::Startup { what: "the test" })
            } else {
                Ok(())
            }
        }
    }

    impl Hal for Scripted {
        fn name(&self) -> &'static str {
            "canopen"
        }
        fn read(&mut self, t: f64, _period: f64) -> Result<Measurements, HalError> {
            self.calls.push("read");
            Ok(Measurements {
                t,
                ..Measurements::UNMEASURED
            })
        }
        fn write(&mut self, _t: f64, _period: f64, _command: f64) -> Result<(), HalError> {
            Ok(())
        }
        fn safe_stop(&mut self, _command: f64) -> Result<(), HalError> {
            self.calls.push("safe_stop");
            Ok(())
        }
        fn configure(&mut self) -> Result<(), HalError> {
            self.lifecycle("configure")
        }
        fn activate(&mut self) -> Result<(), HalError> {
            self.lifecycle("activate")
        }
        fn take_startup_report(&mut self) -> Option<StartupReport> {
            self.report.take()
        }
    }

    fn report(settings_error: bool, stopped: bool) -> StartupReport {
        let frame = CanFrameRecord {
            t_ns: -1_000,
            id: 0x701,
            extended: false,
            dlc: 1,
            data: [5, 0, 0, 0, 0, 0, 0, 0],
            tx: true,
        };
        StartupReport {
            reason: "CANopen start-up: scripted".into(),
            channel: "canopen start-up",
            settings_error,
            stopped,
            elapsed_s: 0.25,
            time_limit_s: Some(0.2),
            frames: vec![frame, frame],
        }
    }

    fn run_scripted(
        hal: &mut Scripted,
        mcap: &std::path::Path,
        atomic_log: bool,
    ) -> Result<Session, SessionError> {
        let cfg = boom();
        let opts = SessionOptions {
            duration: Some(0.002),
            mcap: Some(mcap.to_path_buf()),
            atomic_log,
            bus: Some("socketcand://127.0.0.1:1/can0".into()),
            ..Default::default()
        };
        let backend = Backend {
            hal,
            pacer: &mut SimulatedTime,
            overflow: Overflow::Block,
            substeps: 0,
        };
        run_with(&cfg, backend, opts)
    }

    /// Runs a scripted backend that fails at lifecycle call `fail_at` with `report`: the
    /// session must end at start-up. Returns the backend's calls and the failure.
    fn failed_start(
        fail_at: &'static str,
        report: Option<StartupReport>,
        out: &std::path::Path,
        atomic_log: bool,
    ) -> (Vec<&'static str>, Box<FailedStartup>) {
        let mut hal = Scripted {
            fail_at: Some(fail_at),
            report,
            calls: Vec::new(),
        };
        let Err(SessionError::Startup(f)) = run_scripted(&mut hal, out, atomic_log) else {
            panic!("a failed {fail_at} must end the session before the loop");
        };
        (hal.calls, f)
    }

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("ehactl_session_{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        dir.join(name)
    }

    #[test]
    fn a_failed_activate_is_logged_as_a_startup_trip() {
        for atomic in [false, true] {
            let out = temp(&format!("activate_{atomic}.mcap"));
            let (calls, f) = failed_start("activate", Some(report(false, false)), &out, atomic);
            assert_eq!(calls, ["configure", "activate"], "no cycle ran");
            let s = f.log.expect("logged").expect("a summary");
            assert_eq!(s["trip"], "CANopen start-up: scripted");
            assert_eq!(s["trip_kind"], "startup");
            assert_eq!(s["exit_code"], EXIT_STARTUP);
            assert_eq!(s["can_startup_frames"], 2);
            assert_eq!(s["bus"], "socketcand://127.0.0.1:1/can0");
            assert_eq!(s["records_written"], 0);
            assert_eq!(s["mcap"], out.display().to_string());
            assert!(out.is_file(), "the log is at its name, atomic or not");
        }
    }

    #[test]
    fn a_stopped_startup_is_logged_as_interrupted_and_a_settings_error_not_at_all() {
        let out = temp("stopped.mcap");
        let (calls, f) = failed_start("configure", Some(report(false, true)), &out, false);
        assert_eq!(calls, ["configure"]);
        let s = f.log.expect("logged").expect("a summary");
        assert_eq!(s["interrupted"], true);
        assert!(s["trip"].is_null() && s["trip_kind"].is_null());
        assert_eq!(s["startup_stopped"], "CANopen start-up: scripted");
        assert_eq!(s["exit_code"], EXIT_STOPPED);

        let out = temp("settings.mcap");
        let (_, f) = failed_start("configure", Some(report(true, false)), &out, false);
        assert!(f.report.settings_error);
        assert!(
            matches!(f.log, Ok(None)),
            "nothing reached the hardware: no log"
        );
        assert!(!out.exists());
    }

    #[test]
    fn a_lifecycle_error_without_a_report_is_logged_as_the_error_itself() {
        let out = temp("no_report.mcap");
        let (_, f) = failed_start("configure", None, &out, false);
        assert_eq!(f.report.channel, "start-up", "not named after a backend");
        assert!(f.report.frames.is_empty());
        let s = f.log.expect("logged").expect("a summary");
        assert_eq!(s["trip"], f.report.reason);
        assert!(
            s["trip"].as_str().is_some_and(|t| t.contains("the test")),
            "{s}"
        );
        assert_eq!(s["exit_code"], EXIT_STARTUP);
    }

    #[test]
    fn a_backend_is_configured_and_activated_before_its_first_read() {
        let out = temp("ok.mcap");
        let mut hal = Scripted {
            fail_at: None,
            report: None,
            calls: Vec::new(),
        };
        let _ = run_scripted(&mut hal, &out, false);
        assert_eq!(hal.calls[..3], ["configure", "activate", "read"]);
    }
}
