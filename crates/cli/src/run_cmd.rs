//! `ehactl run`: one closed-loop run, in four phases — check everything that can be checked
//! before anything starts ([`prepare`]), start the services around the loop (control socket,
//! the CAN backend unconfigured, live view: [`Services::start`]), bring the backend up and
//! run the loop with a progress bar ([`execute`], through `ehactl_runtime::session`, which
//! also logs a failed start-up), and report ([`report`]). Exit codes as listed in `main.rs`.

use crate::canbus::{self, HalKind};
use crate::{
    check_log_path, config_error, default_log_path, live, load, progress_bar, sig, stop_flag,
};
use ehactl_config::{ControlMode, RigConfig};
use ehactl_hal::pacer::TimingReport;
use ehactl_hal::Hal;
use ehactl_log::logger::LogTap;
use ehactl_log::record::{Event, EventKind, Severity};
use ehactl_runtime::control_socket::{ControlServer, StartError};
use ehactl_runtime::live::LiveParams;
use ehactl_runtime::session::{
    run_realtime, run_sim, run_sim_live, Session, SessionError, SessionOptions,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// The command line of `ehactl run` (clap reads the doc comments as its `--help`).
#[derive(clap::Args)]
pub struct RunArgs {
    /// Rig config (TOML).
    pub config: PathBuf,
    /// Override run.duration (s).
    #[arg(long, allow_negative_numbers = true)]
    pub duration: Option<f64>,
    /// MCAP output file (default: out/<config name>.mcap).
    // The doc comment is clap's `--help` text, printed as written: `<config name>` is
    // no HTML tag.
    #[allow(rustdoc::invalid_html_tags)]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print exactly one JSON object with the summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Pace the loop against the wall clock (the [realtime] section: SCHED_FIFO,
    /// mlockall, CPU affinity, overrun policy); with the sim backend the plant then
    /// runs in real time. Timing statistics go to the summary and the MCAP log.
    // `--help` text, printed as written: `[realtime]` is the config section, no link.
    #[allow(rustdoc::broken_intra_doc_links)]
    #[arg(long)]
    pub realtime: bool,
    /// Serve live gain / setpoint changes on this Unix socket (see `ehactl set`).
    #[arg(long, value_name = "PATH")]
    pub control_socket: Option<PathBuf>,
    /// Backend: `sim` (in-process plant) or `canopen` (CiA 406 transducer + CiA 408
    /// valve on a CAN bus, paced by the wall clock; needs --bus).
    #[arg(long, value_enum, default_value = "sim")]
    pub hal: HalKind,
    /// CAN bus for --hal canopen: socketcan://IFACE or socketcand://HOST:PORT/CHANNEL.
    #[arg(long, value_name = "URL")]
    pub bus: Option<String>,
    /// Overwrite --out even if it is an existing file that is not an MCAP log (never the
    /// config being run).
    #[arg(long)]
    pub force: bool,
    /// Serve the run live to Foxglove (Foxglove WebSocket protocol, same channels as the
    /// MCAP log) on HOST:PORT (default 127.0.0.1:8765; port 0 = any free port). Best with
    /// --realtime; messages a viewer cannot take are dropped and counted, never waited for.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = live::DEFAULT_ADDR)]
    pub live: Option<String>,
    /// Most live-view clients served at once (counted from a complete upgrade request); more
    /// are refused (HTTP 503) and counted in the summary's `live.clients_refused_over_limit`.
    /// A connection has 5 s to complete its upgrade. Each idle subscribed client costs a
    /// share of 16 MiB of queued messages (at most 1 MiB).
    #[arg(long, value_name = "N", default_value_t = crate::live_front::DEFAULT_MAX_CLIENTS,
          value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub live_max_clients: u16,
}

/// Run `ehactl run`.
pub fn cmd_run(args: RunArgs) -> ExitCode {
    let (cfg, out) = match prepare(&args) {
        Ok(v) => v,
        Err(code) => return code,
    };
    let live = Arc::new(LiveParams::new());
    let mut services = match Services::start(&args, &cfg, &live) {
        Ok(s) => s,
        Err(code) => return code,
    };
    let start_events = stability_warning(&args.config, &cfg);
    let result = execute(&args, &cfg, out.clone(), &mut services, &live, start_events);
    // After a failed start-up no run log was opened, so nothing will close the tap: no wait.
    let drain = match result {
        Err(SessionError::Startup(_)) => Duration::ZERO,
        _ => Duration::from_secs(5),
    };
    let live_stats = services.live_view.take().map(|v| {
        let url = v.url.clone();
        (url, v.finish(drain, Duration::from_millis(500)))
    });
    let session = match result {
        Ok(s) => s,
        Err(SessionError::Config(e)) => {
            return config_error(format!("{}: {e}", args.config.display()))
        }
        Err(SessionError::Startup(f)) => return canbus::startup_failed(&f, &out, args.json),
        Err(SessionError::Log(e)) => {
            let msg = if e.at_create {
                // The loop never started: nothing to stop, nothing to recover.
                format!("{e}; nothing was run")
            } else {
                format!(
                    "{e}; the run was stopped (valve to safe command); what reached the file can be rebuilt with `ehactl recover {} NEW.mcap`",
                    e.path.display()
                )
            };
            eprintln!("ehactl: {msg}");
            if args.json {
                // `--json` promises one object on stdout, failures included. Not println!: a
                // full disk must not turn into a panic on a closed stdout.
                use std::io::Write;
                let obj = serde_json::json!({
                    "error": msg,
                    "error_kind": "log",
                    "mcap": e.path.display().to_string(),
                    "exit_code": 1,
                });
                let _ = writeln!(std::io::stdout(), "{obj}");
            }
            return ExitCode::from(1);
        }
    };
    report(&args, &cfg, &session, live_stats.as_ref());
    exit_code(&session)
}

/// Phase 1: everything that can be refused before anything starts (exit 2, or 1 for an
/// unwritable log), so that no error leaves a brought-up rig or an empty log behind.
fn prepare(args: &RunArgs) -> Result<(RigConfig, PathBuf), ExitCode> {
    let cfg = load(&args.config)?;
    if let Some(d) = args.duration {
        if let Err(why) = ehactl_runtime::session::check_duration(d) {
            return Err(config_error(format!("--duration {d}: {why}")));
        }
    }
    if let Some(Err(e)) = args.live.as_deref().map(live::parse_addr) {
        return Err(config_error(e));
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_log_path(&args.config, ""));
    // Bad --hal/--bus or CAN settings: exit 2 before the log file is created.
    canbus::check_args(&cfg, &args.config, (args.hal, args.bus.as_deref()))?;
    check_log_path(&out, &args.config, args.force)?;
    if let Err(msg) = crate::log_writable(&out) {
        return Err(io_failure(args, &msg, "out"));
    }
    Ok((cfg, out))
}

/// A start-up I/O failure of `ehactl run` (exit 1): the message on stderr and, with `--json`,
/// the one JSON object `--json` promises (`error`, `error_kind`, `exit_code`; docs/usage.md).
fn io_failure(args: &RunArgs, msg: &str, kind: &str) -> ExitCode {
    eprintln!("ehactl: {msg}");
    if args.json {
        // Not println!: a closed stdout must not turn into a panic.
        use std::io::Write;
        let obj = serde_json::json!({"error": msg, "error_kind": kind, "exit_code": 1});
        let _ = writeln!(std::io::stdout(), "{obj}");
    }
    ExitCode::from(1)
}

/// Phase 2: what runs beside the loop, and the CAN backend (unconfigured until the session
/// brings it up). Dropped at the end of the command (the control socket is removed, the CAN
/// rig is released after its safe stop).
struct Services {
    _control: Option<ControlServer>,
    can_hal: Option<ehactl_canopen::hal::CanopenHal>,
    live_view: Option<live::LiveView>,
    stop: Arc<AtomicBool>,
}

impl Services {
    fn start(
        args: &RunArgs,
        cfg: &RigConfig,
        live: &Arc<LiveParams>,
    ) -> Result<Services, ExitCode> {
        // The socket and the live view are opened before the CAN bring-up (in the session),
        // so that their errors never leave a started rig.
        let control = match &args.control_socket {
            Some(path) => match ControlServer::start(path, cfg.clone(), live.clone()) {
                Ok(s) => Some(s),
                Err(StartError::PathInUse(e)) => {
                    return Err(config_error(format!(
                        "--control-socket {}: {e}",
                        path.display()
                    )));
                }
                Err(e) => {
                    let msg = format!("--control-socket {}: {e}", path.display());
                    return Err(io_failure(args, &msg, "control_socket"));
                }
            },
            None => None,
        };
        let stop = stop_flag();
        // No bus I/O yet: the session brings the rig up before the loop (may block up to
        // canopen.boot_timeout_s); a signal meanwhile ends the start-up within one master
        // heartbeat period (exit 130, the valve back to HOLD if it was being enabled); a
        // signal after it ends the run at its first cycle, through the safe stop.
        let can_hal = canbus::backend(
            cfg,
            &args.config,
            (args.hal, args.bus.as_deref()),
            args.json,
            &stop,
        )?;
        let live_view = match args
            .live
            .as_deref()
            .map(|a| live::LiveView::start(a, usize::from(args.live_max_clients)))
            .transpose()
        {
            Ok(v) => v,
            Err(e) => return Err(io_failure(args, &e.to_string(), "live")),
        };
        if let Some(v) = &live_view {
            // Parsed by tests and scripts: the URL is the last word.
            eprintln!("ehactl: live view (Foxglove WebSocket) on {}", v.url);
        }
        Ok(Services {
            _control: control,
            can_hal,
            live_view,
            stop,
        })
    }
}

/// Phase 3: the backend's start-up and the loop, under wall-clock pacing (`--realtime` or a
/// CAN rig) or simulated time, with a progress bar on a terminal.
fn execute(
    args: &RunArgs,
    cfg: &RigConfig,
    out: PathBuf,
    services: &mut Services,
    live: &LiveParams,
    start_events: Vec<Event>,
) -> Result<Session, SessionError> {
    let tap = services.live_view.as_ref().map(|v| v.tap());
    let bar = progress_bar(String::new());
    let live_ref = args.control_socket.as_ref().map(|_| live);
    let stop = services.stop.clone();
    let result = if args.realtime || services.can_hal.is_some() {
        // The loop thread only stores the cycle count; the bar is drawn by this watcher
        // thread so that no terminal I/O happens in the cycle.
        bar.set_message(format!(
            "{} (real time{})",
            args.config.display(),
            if services.can_hal.is_some() {
                ", canopen"
            } else {
                ""
            }
        ));
        let done = Arc::new(AtomicU64::new(0));
        let total = Arc::new(AtomicU64::new(1));
        let finished = Arc::new(AtomicBool::new(false));
        let watcher = {
            let (bar, done, total, finished) =
                (bar.clone(), done.clone(), total.clone(), finished.clone());
            std::thread::spawn(move || {
                while !finished.load(Ordering::Relaxed) {
                    bar.set_length(total.load(Ordering::Relaxed));
                    bar.set_position(done.load(Ordering::Relaxed));
                    std::thread::sleep(Duration::from_millis(100));
                }
            })
        };
        let mut progress = |k: u64, n: u64| {
            total.store(n, Ordering::Relaxed);
            done.store(k, Ordering::Relaxed);
        };
        let opts = session_options(args, out, &stop, &mut progress, tap, start_events);
        let hardware = services.can_hal.as_mut().map(|h| h as &mut dyn Hal);
        let r = run_realtime(cfg, opts, live_ref, hardware, Some(warn));
        finished.store(true, Ordering::Relaxed);
        let _ = watcher.join();
        r
    } else {
        bar.set_message(format!("{} (simulated)", args.config.display()));
        let mut progress = |k: u64, n: u64| {
            bar.set_length(n);
            bar.set_position(k);
        };
        let opts = session_options(args, out, &stop, &mut progress, tap, start_events);
        if live_ref.is_some() {
            run_sim_live(cfg, opts, live_ref)
        } else {
            run_sim(cfg, opts)
        }
    };
    bar.finish_and_clear();
    result
}

fn session_options<'a>(
    args: &RunArgs,
    out: PathBuf,
    stop: &'a AtomicBool,
    progress: &'a mut dyn FnMut(u64, u64),
    tap: Option<Arc<LogTap>>,
    start_events: Vec<Event>,
) -> SessionOptions<'a> {
    SessionOptions {
        start_events,
        duration: args.duration,
        mcap: Some(out),
        bus: args.bus.clone(),
        stop: Some(stop),
        capture: false,
        progress: Some(progress),
        tap,
        ..Default::default()
    }
}

/// Before the run: the stability verdict of the config's linearised sampled loop
/// (`ehactl analyze`'s). An unstable loop is warned about on stderr and becomes an
/// `unstable_loop` warning event on `/events` (value: the largest closed-loop pole
/// magnitude |z|, limit 1); the run goes on, and its supervisor is what stops it. A
/// linearisation that fails is warned about and the run goes on too.
fn stability_warning(config: &Path, cfg: &RigConfig) -> Vec<Event> {
    let st = match ehactl_analysis::analyze::stability(cfg) {
        Ok(Some(st)) => st,
        Ok(None) => return Vec::new(),
        Err(e) => {
            warn(&format!(
                "{}: the loop's stability could not be checked ({e})",
                config.display()
            ));
            return Vec::new();
        }
    };
    if st.stable {
        return Vec::new();
    }
    warn(&format!(
        "{}: the linearised loop is {}; expect the supervisor to trip (`ehactl analyze {}` for the margins)",
        config.display(),
        crate::analysis_cmd::stability_text(&st),
        config.display()
    ));
    vec![Event {
        value: st.max_pole_magnitude,
        limit: 1.0,
        unit: "-",
        ..Event::note(
            0.0,
            0,
            Severity::Warning,
            EventKind::UnstableLoop,
            "linearised_loop",
        )
    }]
}

/// Warnings of the wall-clock pacer's set-up (SCHED_FIFO, mlockall, affinity refused).
fn warn(msg: &str) {
    eprintln!("ehactl: warning: {msg}");
}

/// Phase 4: the summary, as one JSON object (`--json`) or as text.
fn report(
    args: &RunArgs,
    cfg: &RigConfig,
    session: &Session,
    live_stats: Option<&(String, live::LiveStats)>,
) {
    let mut summary = session.summary_json();
    if let Some((_, st)) = live_stats {
        if st.direct_sdk_clients > 0 {
            eprintln!(
                "ehactl: warning: --live: {} connection(s) reached the live view's internal Foxglove SDK port directly (a local process bypassing the front); each was cut off before any channel was advertised to it (live.direct_sdk_clients)",
                st.direct_sdk_clients
            );
        }
    }
    if let Some((url, st)) = live_stats {
        summary["live"] = serde_json::json!({
            "url": url,
            "messages_published": st.published,
            "messages_dropped": st.dropped,
            "clients_at_end": st.clients,
            "client_messages_dropped": st.client_dropped(),
            "connections_refused": st.refused,
            "max_clients": st.max_clients,
            "clients_refused_over_limit": st.over_limit,
            "direct_sdk_clients": st.direct_sdk_clients,
            "clients": st.per_client.iter().map(|c| serde_json::json!({
                "peer": c.peer.to_string(),
                "subprotocol": c.subprotocol,
                "messages_sent": c.messages_sent,
                "messages_dropped": c.messages_dropped,
            })).collect::<Vec<_>>(),
        });
    }
    if args.json {
        // Not println!: a reader that went away (`| head`) must not turn a finished run
        // into a panic.
        use std::io::Write;
        let _ = writeln!(std::io::stdout(), "{summary}");
    } else {
        print_text_summary(&args.config, cfg, session, &summary, live_stats);
    }
}

fn print_text_summary(
    config: &Path,
    cfg: &RigConfig,
    session: &Session,
    summary: &serde_json::Value,
    live_stats: Option<&(String, live::LiveStats)>,
) {
    let o = &session.outcome;
    println!("ehactl run {}", config.display());
    println!(
        "  cycles        {} at {} Hz ({} s {}, {} substeps/cycle)",
        o.cycles,
        sig(session.control_rate_hz, 6),
        sig(o.duration_s, 6),
        if session.timing.is_some() {
            "run"
        } else {
            "simulated"
        },
        session.substeps
    );
    if cfg.control.mode == ControlMode::OpenLoop {
        // No feedback: the setpoint (V) is the valve command, there is no tracking error.
        println!("  error         none: open loop (the setpoint is the valve command, V); see the log for the response");
    } else {
        println!(
            "  rms error     {} {} (after start of dynamics: {} {})",
            sig(o.rms_error, 4),
            session.unit,
            sig(o.rms_error_settled, 4),
            session.unit
        );
        println!(
            "  max |error|   {} {}",
            sig(o.max_abs_error, 4),
            session.unit
        );
    }
    println!(
        "  speed         {}× real time ({} s wall)",
        sig(summary["sim_speed_x_realtime"].as_f64().unwrap_or(0.0), 3),
        sig(session.wall_time_s, 3)
    );
    if let Some(l) = &session.log {
        println!(
            "  mcap          {} ({} cycles, {} dropped, queue high water {} of {})",
            l.path.display(),
            l.records_written,
            l.records_dropped,
            l.queue_high_water,
            l.queue_capacity
        );
    }
    if let Some((url, st)) = live_stats {
        print_live_summary(url, st);
    }
    canbus::print_summary(summary);
    if let Some(tm) = &session.timing {
        print_timing(tm, summary["cycles"].as_u64().unwrap_or(0));
    }
    match (&o.trip, o.interrupted) {
        (Some(t), _) => println!("  TRIP          {}", t.describe()),
        (None, true) => {
            println!("  interrupted by signal; valve set to safe command, log finalised")
        }
        _ => println!("  trip          none"),
    }
}

/// The `--live` lines: messages published and dropped, clients refused, slow clients.
fn print_live_summary(url: &str, st: &live::LiveStats) {
    println!(
        "  live          {url}: {} messages published, {} dropped before the server, {} client(s) at the end",
        st.published, st.dropped, st.clients
    );
    if st.over_limit > 0 {
        println!(
            "  live refused  {} client(s) beyond --live-max-clients {}",
            st.over_limit, st.max_clients
        );
    }
    let slow: Vec<_> = st
        .per_client
        .iter()
        .filter(|c| c.messages_dropped > 0)
        .collect();
    println!(
        "  live clients  {} connected, {} missed messages (too slow to read): {} messages dropped in all{}",
        st.per_client.len(),
        slow.len(),
        st.client_dropped(),
        slow.iter()
            .max_by_key(|c| c.messages_dropped)
            .map_or(String::new(), |c| format!(
                "; worst {} got {} and missed {}",
                c.peer, c.messages_sent, c.messages_dropped
            ))
    );
}

/// The wall-clock lines: jitter, period and execution time (µs), overruns of `cycles`,
/// the real-time settings applied.
fn print_timing(tm: &TimingReport, cycles: u64) {
    println!(
        "  jitter        p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs (start − deadline)",
        tm.jitter.p50, tm.jitter.p99, tm.jitter.p999, tm.jitter.max
    );
    println!(
        "  period        p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs (nominal {:.1} µs)",
        tm.period.p50, tm.period.p99, tm.period.max, tm.period_nominal_us
    );
    println!(
        "  exec          p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs (cycle start → next wait)",
        tm.exec.p50, tm.exec.p99, tm.exec.p999, tm.exec.max
    );
    println!(
        "  exec CPU      p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs (thread CPU time, preemptions excluded)",
        tm.exec_cpu.p50, tm.exec_cpu.p99, tm.exec_cpu.p999, tm.exec_cpu.max
    );
    if tm.exec_cpu_clamped > 0 {
        println!(
            "                {} cycles read more CPU time than wall time (core clocks out of step) and count as their wall time",
            tm.exec_cpu_clamped
        );
    }
    println!(
        "  overruns      {} of {} cycles: {} ours (CPU time over the period), {} thread not running (late start or preempted); longest streak {}, {} deadlines skipped, policy {}",
        tm.overruns,
        cycles,
        tm.overruns_exec,
        tm.overruns_wakeup,
        tm.longest_overrun_streak,
        tm.skipped_deadlines,
        tm.overrun_policy
    );
    println!(
        "  rt            SCHED_FIFO {}, CPU {}, memory {}",
        tm.rt
            .sched_fifo_priority
            .map_or("off".to_string(), |p| format!("priority {p}")),
        tm.rt.cpu.map_or("any".to_string(), |c| c.to_string()),
        if tm.rt.memory_locked {
            "locked"
        } else {
            "not locked"
        }
    );
}

/// 3 on a trip, 130 after a signal, 0 otherwise.
fn exit_code(session: &Session) -> ExitCode {
    if session.outcome.trip.is_some() {
        ExitCode::from(3)
    } else if session.outcome.interrupted {
        ExitCode::from(130)
    } else {
        ExitCode::SUCCESS
    }
}
