//! `ehactl`: closed-loop runs against the simulated plant or CANopen devices (`--hal
//! canopen`), config checks, parameter lists, analysis and diagnosis.
//!
//! Exit codes: 0 run completed, 2 bad config or arguments, 3 supervisor trip (including
//! device faults of `--hal canopen`), 4 hardware start-up failed (bus, boot-up, SDO
//! configuration, device state), 130 interrupted by a signal (log finalised), 1 any other
//! failure (I/O).

mod analysis_cmd;

mod canbus;

#[cfg(feature = "diagnosis")]
mod diagnose;
mod fmu_cmd;
mod live;
mod live_front;
mod run_cmd;

use clap::{Parser, Subcommand};
use ehactl_config::registries;
use ehactl_config::RigConfig;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "ehactl",
    version,
    about = "Real-time electro-hydraulic actuator controller: runs against a simulated plant \
             or CANopen devices (run --hal canopen)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a closed-loop test of CONFIG and log it to MCAP: against the simulated plant
    /// (default, --hal sim) or CANopen devices on a CAN bus (--hal canopen --bus …).
    Run(run_cmd::RunArgs),
    /// Rebuild a valid, indexed MCAP file from a log whose writer was killed (SIGKILL, power
    /// loss, full disk): every intact chunk is kept, a cut-off one is dropped.
    Recover {
        /// Damaged MCAP log.
        input: PathBuf,
        /// New file to write (must not exist).
        output: PathBuf,
        /// Print exactly one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Change gains or setpoint parameters of a running `ehactl run --control-socket PATH`;
    /// the change lands at a cycle boundary and is logged as a `param_change` event.
    Set {
        /// Control socket of the running process.
        #[arg(long, value_name = "PATH")]
        socket: PathBuf,
        /// One or more PATH=VALUE (units as listed by `ehactl params`), e.g. control.pi.kp=0.5.
        #[arg(required = true, value_name = "PATH=VALUE")]
        assignments: Vec<String>,
    },
    /// Validate CONFIG and print what it sets up.
    CheckConfig {
        /// Rig config (TOML).
        config: PathBuf,
    },
    /// List every config parameter with its unit and meaning.
    Params,
    /// Export CONFIG as an FMI 2.0 co-simulation FMU (the plant, or with --closed-loop the
    /// control loop around it) for Simulink, OpenModelica, Dymola or FMPy (docs/fmu.md).
    ExportFmu(fmu_cmd::ExportFmuArgs),
    /// Linearise CONFIG around its operating point: natural frequencies, margins, bandwidths.
    Analyze {
        /// Rig config (TOML).
        config: PathBuf,
        /// Print exactly one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Find what the simulation of CONFIG gets wrong on measured data, name the cause from the
    /// effect catalogue, extend the model and measure the gain on held-out data.
    Diagnose {
        /// Nominal rig config (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Measured data: CSV (t, u, any of force, x, p_a, p_b, x_v, ref, v and the config's
        /// declared [inputs] columns; SI) or MCAP (an ehactl log, or a lab record: JSON
        /// samples with those column names on /measured). Give it several times for a
        /// campaign: one load law fitted to every record, coefficients depending on the
        /// declared operating inputs; a record with x and force but no u / ref (a
        /// displacement-controlled test) is diagnosed as a campaign too.
        // `--help` text, printed as written: `[inputs]` is the config section, no link.
        #[allow(rustdoc::broken_intra_doc_links)]
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Separate validation record (default: the last 30 % of each --data is held out);
        /// several for a campaign (held out whole, e.g. an operating point never fitted).
        #[arg(long)]
        validate: Vec<PathBuf>,
        /// Output directory for extended.toml, report.md and plots: new, empty, or written by
        /// an earlier diagnosis (never over an input).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write into an --out directory that holds other files (same-named ones are replaced;
        /// the inputs never are).
        #[arg(long)]
        force: bool,
        /// Diagnose an ehactl MCAP log although the config it was logged with differs from
        /// --config in the rig's fixed quantities (geometry, supply, valve, control mode).
        #[arg(long)]
        allow_config_mismatch: bool,
        /// Print exactly one JSON object on stdout.
        #[arg(long)]
        json: bool,
        /// Estimate a constant zero offset per measured channel for every model (fitted on the
        /// fitting part, carried to the held-out part); by default the sensors' zeros are
        /// trusted.
        #[arg(long)]
        sensor_offsets: bool,
    },
    /// Replay records through a model (a config or the extended.toml a diagnosis wrote) and
    /// score each measured channel: closed loop, open loop, or with the record's motion
    /// imposed on the rod (records with x and force only).
    Predict {
        /// The model (rig config TOML).
        #[arg(long)]
        config: PathBuf,
        /// Records to predict (CSV, or MCAP: an ehactl log or JSON samples on /measured), one
        /// or more.
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Impose each record's measured motion on the rod and predict the force, whatever
        /// other columns it has.
        #[arg(long)]
        imposed_motion: bool,
        /// Score only the last 30 % of each record (the part a diagnosis holds out).
        #[arg(long)]
        held_out: bool,
        /// Output directory for prediction.json and prediction.svg (new, empty, or written by
        /// ehactl before).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write into an --out directory that holds other files.
        #[arg(long)]
        force: bool,
        /// Print exactly one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Measure the frequency response of the nonlinear plant by a stepped sine (logged to MCAP).
    Sweep(analysis_cmd::SweepArgs),
    /// CAN bus tools (the socketcand-compatible hub).
    Canbus {
        #[command(subcommand)]
        command: canbus::CanbusCommand,
    },
}

pub(crate) fn config_error(e: impl std::fmt::Display) -> ExitCode {
    eprintln!("ehactl: {e}");
    ExitCode::from(2)
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub(crate) fn progress_bar(msg: String) -> ProgressBar {
    let bar = styled_bar("{spinner} {msg} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}");
    bar.set_message(msg);
    bar
}

/// A bar on stderr drawn with the indicatif `template` (hidden when stderr is not a terminal).
pub(crate) fn styled_bar(template: &str) -> ProgressBar {
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// `out/<config file stem><suffix>.mcap`, where runs are logged unless `--out` says otherwise.
pub(crate) fn default_log_path(config: &Path, suffix: &str) -> PathBuf {
    let stem = config
        .file_stem()
        .map_or("run".into(), |s| s.to_string_lossy().into_owned());
    PathBuf::from("out").join(format!("{stem}{suffix}.mcap"))
}

/// Refuse a log path that would destroy something of the user's: the config being run
/// (always), a directory, or an existing file that is not an MCAP log (unless `force`); the
/// rules are `ehactl_log::outpath`'s, shared with the Python bindings. An earlier MCAP log
/// at the path is replaced, as a re-run is expected to do.
pub(crate) fn check_log_path(out: &Path, config: &Path, force: bool) -> Result<(), ExitCode> {
    use ehactl_log::outpath::{self, LogPathError, Naming};
    let naming = Naming {
        arg: "--out",
        force_hint: "add --force",
    };
    match outpath::check_log_path(out, &[config], force, naming) {
        Ok(()) => Ok(()),
        Err(LogPathError::Refused(m)) => Err(config_error(m)),
        Err(LogPathError::Busy(m)) => {
            eprintln!("ehactl: {m}");
            Err(ExitCode::from(1))
        }
    }
}

/// Fail before anything starts (CAN bring-up, the loop) if the log cannot be written: the
/// message (`--out PATH: cannot write the MCAP log: …`), which `ehactl run` prints (and with
/// `--json` puts in its one JSON object) before exiting 1.
pub(crate) fn log_writable(out: &Path) -> Result<(), String> {
    let fail =
        |e: std::io::Error| format!("--out {}: cannot write the MCAP log: {e}", out.display());
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(fail)?;
    }
    let existed = std::fs::symlink_metadata(out).is_ok();
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(out)
        .map(drop)
        .map_err(fail)?;
    if !existed {
        // Only a probe: a run that fails before logging must not leave an empty file.
        let _ = std::fs::remove_file(out);
    }
    Ok(())
}

/// `ehactl recover IN OUT`.
fn cmd_recover(input: &Path, output: &Path, json: bool) -> ExitCode {
    if std::fs::symlink_metadata(output).is_ok() {
        return config_error(format!(
            "{}: exists; recover writes a new file and never overwrites one",
            output.display()
        ));
    }
    // The CLI's bounded read of user input: a regular file of at most
    // `ehactl_input::RECOVER_MAX_BYTES`; a FIFO, /dev/zero or a directory is refused without
    // blocking, a file that does not start with the MCAP magic before the rest is read.
    let (file, len) =
        match ehactl_input::open_bounded(input, ehactl_input::RECOVER_MAX_BYTES, "MCAP log") {
            Ok(f) => f,
            Err(e) => return config_error(format!("recover: {e}")),
        };
    let data = match ehactl_log::recover::read_log(std::io::BufReader::new(file), len) {
        Ok(d) => d,
        Err(e) => return config_error(format!("recover: {}: {e}", input.display())),
    };
    // A log a running ehactl still holds the lock of is being written: what is read is a
    // snapshot of it, said so (the writer's lock, ehactl_log::logger).
    let writer_active = ehactl_log::logger::is_locked(input);
    if writer_active {
        eprintln!(
            "ehactl: recover: {}: is still being written by a running ehactl (it holds the file's lock); recovering a snapshot of its first {} bytes (the log is complete once that run ends)",
            input.display(),
            data.len()
        );
    }
    match ehactl_log::recover::recover_bytes(&data, output)
        .map_err(|e| format!("{}: {e}", input.display()))
    {
        Ok(rep) => {
            if json {
                print_recover_json(input, output, &rep, writer_active);
            } else {
                print_recover_text(input, output, &rep, writer_active);
            }
            // What was lost, and where, goes to stderr even with --json.
            for p in &rep.problems {
                eprintln!("ehactl: recover: {p}");
            }
            if rep.total_messages() == 0 {
                // Nothing of the run was kept: a failure, and no empty file left behind.
                let _ = std::fs::remove_file(output);
                eprintln!(
                    "ehactl: recover: {}: no message could be recovered ({} chunks dropped, {} messages without their channel); {} not written",
                    input.display(),
                    rep.bad_chunks,
                    rep.messages_without_channel,
                    output.display()
                );
                return ExitCode::from(1);
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("ehactl: recover: {e}");
            ExitCode::from(2)
        }
    }
}

/// `ehactl recover --json`: the report of recovering `input` into `output` as one JSON
/// object on stdout.
fn print_recover_json(
    input: &Path,
    output: &Path,
    rep: &ehactl_log::recover::RecoverReport,
    writer_active: bool,
) {
    println!(
        "{}",
        serde_json::json!({
            "input": input.display().to_string(),
            "output": output.display().to_string(),
            "was_complete": rep.was_complete,
            "stopped_early": rep.stopped_early,
            "chunks": rep.chunks,
            "bad_chunks": rep.bad_chunks,
            "chunks_indexed": rep.chunks_indexed,
            "skipped_bytes": rep.skipped_bytes,
            "messages": rep.messages,
            "messages_total": rep.total_messages(),
            "messages_without_channel": rep.messages_without_channel,
            "problems": rep.problems,
            "last_time_s": rep.last_time_s,
            "writer_active": writer_active,
        })
    );
}

/// `ehactl recover`: the report of recovering `input` into `output` as text on stdout
/// (times in s).
fn print_recover_text(
    input: &Path,
    output: &Path,
    rep: &ehactl_log::recover::RecoverReport,
    writer_active: bool,
) {
    println!("ehactl recover {} → {}", input.display(), output.display());
    println!(
        "  input         {}",
        match (writer_active, rep.was_complete, rep.stopped_early) {
            (true, _, _) => "still being written by a running ehactl (a snapshot was recovered)",
            (false, true, _) => "complete (had its footer and chunk index)",
            (false, false, true) => "cut off: no footer, the last record incomplete",
            (false, false, false) => "no footer",
        }
    );
    println!(
        "  chunks        {} kept, {} dropped (bad size, compression, CRC or contents){}",
        rep.chunks,
        rep.bad_chunks,
        rep.chunks_indexed
            .map_or(String::new(), |n| format!("; the chunk index lists {n}"))
    );
    if rep.skipped_bytes > 0 {
        println!(
            "  skipped       {} bytes that are not readable records",
            rep.skipped_bytes
        );
    }
    println!("  messages      {} kept", rep.total_messages());
    for (topic, n) in &rep.messages {
        println!("  {topic:<13} {n} messages");
    }
    if rep.messages_without_channel > 0 {
        println!(
            "  not copied    {} messages whose channel record was lost",
            rep.messages_without_channel
        );
    }
    println!("  last message  t = {:.4} s", rep.last_time_s);
}

/// `v` with `digits` significant digits, without float noise (`3.05`, not
/// `3.0500000000000003`); scientific notation outside 1e-3 ≤ |v| < 1e6.
pub(crate) fn sig(v: f64, digits: usize) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    if v == 0.0 {
        return "0".into();
    }
    let digits = digits.max(1);
    let e = v.abs().log10().floor() as i32;
    if (-3..6).contains(&e) {
        let decimals = (digits as i32 - 1 - e).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{v:.*e}", digits - 1)
    }
}

/// Stop flag set by SIGINT / SIGTERM.
pub(crate) fn stop_flag() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, stop.clone()) {
            eprintln!("ehactl: warning: cannot install signal handler: {e}");
        }
    }
    stop
}

pub(crate) fn load(path: &Path) -> Result<RigConfig, ExitCode> {
    RigConfig::load(path).map_err(|e| config_error(config_load_message(path, &e)))
}

/// One line for a config that failed to load: the file, then the field and the problem. A
/// file that cannot be read is its own "field", so it is named once, not twice.
pub(crate) fn config_load_message(path: &Path, e: &ehactl_plant::spec::ConfigError) -> String {
    if e.path == path.display().to_string() {
        format!("{}: {}", path.display(), e.message)
    } else {
        format!("{}: {e}", path.display())
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    set_signal_dispositions(&cli.command);
    dispatch(cli.command)
}

/// SIGPIPE and SIGXFSZ as `command` needs them; called before any thread is started.
fn set_signal_dispositions(command: &Command) {
    // Commands that only write to stdout end quietly when the reader goes away
    // (`ehactl diagnose … --json | head`), as Unix filters do: SIGPIPE back to its default.
    // Not for `run`, `set` and `canbus`, which also write to sockets: there a closed peer
    // must be an error to handle, never a silent death with a valve attached.
    if matches!(
        command,
        Command::CheckConfig { .. }
            | Command::Params
            | Command::Analyze { .. }
            | Command::Diagnose { .. }
            | Command::Predict { .. }
            | Command::Sweep(_)
            | Command::Recover { .. }
            | Command::ExportFmu(_)
    ) {
        // SAFETY: restoring a default signal disposition before any thread is started.
        unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    }
    // A file-size limit (`ulimit -f`, RLIMIT_FSIZE) must not kill the process with SIGXFSZ
    // (no message, and on `run` no safe command to the valve): ignored, a write past the
    // limit fails with EFBIG and is handled as any other write error (a log failure on `run`).
    // SAFETY: setting a signal disposition before any thread is started.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
}

/// Hand the parsed subcommand to its `cmd_*` function; returns its exit code.
fn dispatch(command: Command) -> ExitCode {
    match command {
        Command::Run(args) => run_cmd::cmd_run(args),
        Command::Recover {
            input,
            output,
            json,
        } => cmd_recover(&input, &output, json),
        Command::Set {
            socket,
            assignments,
        } => cmd_set(&socket, &assignments),
        Command::CheckConfig { config } => cmd_check_config(&config),
        Command::Analyze { config, json } => analysis_cmd::analyze(&config, json),
        Command::Sweep(args) => analysis_cmd::sweep(&args),
        Command::Canbus { command } => canbus::run(command),
        #[cfg(feature = "diagnosis")]
        Command::Diagnose { .. } | Command::Predict { .. } => cmd_diagnosis(command),
        #[cfg(not(feature = "diagnosis"))]
        Command::Diagnose { .. } | Command::Predict { .. } => without_diagnosis(),
        Command::Params => cmd_params(),
        Command::ExportFmu(args) => fmu_cmd::cmd_export_fmu(&args),
    }
}

/// `ehactl check-config CONFIG`.
fn cmd_check_config(config: &Path) -> ExitCode {
    let cfg = match load(config) {
        Ok(c) => c,
        Err(code) => return code,
    };
    // The EDS / DCF files named in [canopen] are loaded and checked as `run --hal
    // canopen` does before it opens the bus (DEPLOY.md: check-config is the go/no-go).
    let can = match canbus::check_config(&cfg, config) {
        Ok(c) => c,
        Err(e) => return config_error(format!("{}: {e}", config.display())),
    };
    match ehactl_runtime::session::build_plant(&cfg) {
        Ok(plant) => {
            if let Some(c) = can {
                println!("{}: {c}", config.display());
            }
            print_config_ok(config, &cfg, &plant);
            ExitCode::SUCCESS
        }
        Err(e) => config_error(format!("{}: {e}", config.display())),
    }
}

/// The `ok` line of `check-config`: control mode, rate (Hz), plant substeps and their
/// length (µs), the effects and what else changes the model.
fn print_config_ok(config: &Path, cfg: &RigConfig, plant: &ehactl_plant::Plant) {
    // Besides the catalogue effects: the grey-box laws `ehactl diagnose` writes
    // and circuit components, which are not catalogue effects but change the model.
    let fx = &cfg.plant.effects;
    let mut other: Vec<&str> = Vec::new();
    if fx.polynomial_force.as_ref().is_some_and(|e| e.enabled) {
        other.push("polynomial_force");
    }
    if fx.polynomial_flow.as_ref().is_some_and(|e| e.enabled) {
        other.push("polynomial_flow");
    }
    let grey_box = if other.is_empty() {
        String::new()
    } else {
        format!(", grey-box terms: [{}]", other.join(", "))
    };
    let cbv = if fx.counterbalance_valve.is_some() {
        ", counterbalance valves"
    } else {
        ""
    };
    println!(
        "{}: ok — mode {}, {} Hz control, {} substeps of {:.3} µs, effects: [{}]{grey_box}{cbv}",
        config.display(),
        serde_json::to_value(cfg.control.mode)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default(),
        sig(cfg.run.control_rate_hz, 6),
        plant.substeps(),
        plant.substep_length() * 1e6,
        cfg.plant
            .effects
            .enabled()
            .iter()
            .map(|e| e.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
}

/// `ehactl params`: every registered parameter with its unit and meaning.
fn cmd_params() -> ExitCode {
    for table in registries() {
        for p in table {
            println!("{:<48} {:<12} {}", p.path, p.unit, p.description);
        }
    }
    ExitCode::SUCCESS
}

/// `ehactl diagnose` and `ehactl predict`: `command` is one of the two.
#[cfg(feature = "diagnosis")]
fn cmd_diagnosis(command: Command) -> ExitCode {
    match command {
        Command::Diagnose {
            config,
            data,
            validate,
            out,
            json,
            sensor_offsets,
            force,
            allow_config_mismatch,
        } => diagnose::cmd_diagnose(
            &config,
            &data,
            &validate,
            out,
            json,
            diagnose::Switches {
                sensor_offsets,
                force,
                allow_config_mismatch,
            },
        ),
        Command::Predict {
            config,
            data,
            imposed_motion,
            held_out,
            out,
            force,
            json,
        } => diagnose::cmd_predict(
            &config,
            &data,
            diagnose::PredictSwitches {
                imposed_motion,
                held_out,
                force,
                json,
            },
            out.as_deref(),
        ),
        _ => unreachable!("dispatch hands only diagnose and predict to cmd_diagnosis"),
    }
}

/// `diagnose` / `predict` in a controller build (`--no-default-features`): exit 2 with the
/// reason and the remedy, never a silent no-op.
#[cfg(not(feature = "diagnosis"))]
fn without_diagnosis() -> ExitCode {
    eprintln!(
        "error: this ehactl was built without the diagnosis (cargo feature `diagnosis`, left \
         out of the controller build for an embedded target); run `diagnose` / `predict` on \
         a workstation build, or rebuild with `--features diagnosis`"
    );
    ExitCode::from(2)
}

fn cmd_set(socket: &Path, assignments: &[String]) -> ExitCode {
    for a in assignments {
        if let Err(e) = ehactl_runtime::live::parse_assignment(a) {
            return config_error(e);
        }
    }
    match ehactl_runtime::control_socket::send(socket, assignments) {
        Ok(reply) if reply.starts_with("ok") => {
            println!("{reply}");
            ExitCode::SUCCESS
        }
        Ok(reply) => {
            eprintln!("ehactl: {}", reply.trim_start_matches("error: "));
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!(
                "ehactl: control socket {}: {e} (is `ehactl run --control-socket` running?)",
                socket.display()
            );
            ExitCode::from(1)
        }
    }
}
