//! `ehactl canbus ...`: CAN bus tools; and the CAN side of `ehactl run --hal canopen`: the
//! checks of `--hal` / `--bus` and the settings before anything is opened ([`check_args`]),
//! the unconfigured backend handed to the session, which brings it up and logs a failed
//! start-up ([`backend`]), and the exit of such a failure ([`startup_failed`]).

use clap::Subcommand;
use ehactl_canopen::hal::{CanopenHal, CanopenSettings};
use ehactl_canopen::hub::Hub;
use ehactl_canopen::BusUrl;
use ehactl_config::RigConfig;
use ehactl_runtime::session::FailedStartup;
use std::io::Write;
use std::path::Path;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// `ehactl canbus` subcommands.
#[derive(Subcommand)]
pub enum CanbusCommand {
    /// socketcand-compatible rawmode hub: relays every frame to every other client, so that
    /// several processes (ehactl, python-can / canopen devices) share one virtual CAN bus.
    /// Prints exactly one line `listening on HOST:PORT` on stdout, then serves until killed.
    Hub {
        /// Address to listen on, HOST:PORT (PORT 0 = pick a free port).
        #[arg(long, default_value = "127.0.0.1:29536")]
        listen: String,
        /// Do not report connects/disconnects on stderr (protocol errors are still reported).
        #[arg(long)]
        quiet: bool,
        /// Hold frames for a new client this long after its rawmode `< ok >` (ms), so that
        /// python-can reads the `< ok >` alone; held frames are delivered afterwards.
        #[arg(long, default_value_t = 200)]
        join_delay_ms: u64,
    },
}

/// Run a `canbus` subcommand.
pub fn run(cmd: CanbusCommand) -> ExitCode {
    match cmd {
        CanbusCommand::Hub {
            listen,
            quiet,
            join_delay_ms,
        } => {
            let hub = match Hub::bind(&listen, quiet) {
                Ok(h) => h.with_join_delay(std::time::Duration::from_millis(join_delay_ms)),
                Err(e) => {
                    eprintln!("ehactl: canbus hub --listen {listen}: cannot listen ({e}); expected a free HOST:PORT such as 127.0.0.1:0");
                    return ExitCode::from(2);
                }
            };
            let addr = match hub.local_addr() {
                Ok(a) => a,
                Err(e) => {
                    eprintln!("ehactl: canbus hub: {e}");
                    return ExitCode::from(1);
                }
            };
            if let Some(w) = crate::live::exposure_warning(
                "canbus hub --listen",
                addr,
                "this CAN bus (read every frame, and send frames that reach the valve)",
            ) {
                eprintln!("{w}");
            }
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "listening on {addr}");
            let _ = out.flush();
            drop(out);
            match hub.serve() {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("ehactl: canbus hub: {e}");
                    ExitCode::from(1)
                }
            }
        }
    }
}

/// `--hal`: which backend a run uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum HalKind {
    /// The in-process simulated plant.
    Sim,
    /// CiA 406 transducer + CiA 408 valve on a CAN bus (needs --bus).
    Canopen,
}

/// The directory of the config file (for relative `[canopen]` EDS / DCF paths).
fn config_dir(config: &Path) -> Option<std::path::PathBuf> {
    config.parent().map(|d| {
        if d.as_os_str().is_empty() {
            std::path::PathBuf::from(".")
        } else {
            d.to_path_buf()
        }
    })
}

pub use ehactl_runtime::session::{EXIT_STARTUP, EXIT_STOPPED};

/// The bus of `--hal`/`--bus`: `None` for the sim backend; exit 2 with one line for a
/// combination that is refused or an address that does not parse.
fn bus_url((hal, bus): (HalKind, Option<&str>)) -> Result<Option<BusUrl>, ExitCode> {
    let arg_err = |m: String| {
        eprintln!("ehactl: {m}");
        ExitCode::from(2)
    };
    match (hal, bus) {
        (HalKind::Sim, None) => Ok(None),
        (HalKind::Sim, Some(b)) => Err(arg_err(format!(
            "--bus {b} needs --hal canopen (the sim backend has no bus)"
        ))),
        (HalKind::Canopen, None) => Err(arg_err(
            "--hal canopen needs --bus socketcan://IFACE or --bus socketcand://HOST:PORT/CHANNEL"
                .into(),
        )),
        (HalKind::Canopen, Some(b)) => BusUrl::parse(b)
            .map(Some)
            .map_err(|e| arg_err(format!("--bus: {e}"))),
    }
}

/// Check `--hal`/`--bus` and the CAN settings that need no bus (exit 2 with one line), before
/// anything is opened or written (the log file included).
/// `config` is the config file (relative EDS / DCF paths of `[canopen]` are taken from its
/// directory).
pub fn check_args(
    cfg: &RigConfig,
    config: &Path,
    hal_bus: (HalKind, Option<&str>),
) -> Result<(), ExitCode> {
    match bus_url(hal_bus)? {
        None => Ok(()),
        Some(url) => CanopenHal::check_settings(&settings(cfg, config, url, false))
            .map(|_plan| ())
            .map_err(|e| {
                eprintln!("ehactl: {e}");
                ExitCode::from(2)
            }),
    }
}

/// The backend settings of `cfg` (file `config`) on bus `url`.
fn settings(cfg: &RigConfig, config: &Path, url: BusUrl, verbose: bool) -> CanopenSettings {
    CanopenSettings {
        bus: url,
        canopen: cfg.canopen.clone(),
        command_full_scale: cfg.plant.valve.command_full_scale,
        control_rate_hz: cfg.timebase().rate_hz(),
        safe_command: cfg.supervisor.safe_command,
        verbose,
        config_dir: config_dir(config),
    }
}

/// `ehactl check-config`'s part of the CAN checks: a config that names its devices' EDS /
/// DCF files (`canopen.transducer_eds`, `canopen.valve_eds`) or further devices
/// (`[[canopen.devices]]`) is meant for `--hal canopen`,
/// so the files are loaded and every check that `run --hal canopen` makes before it opens
/// the bus is made (the same function, [`CanopenHal::check_settings`]: the settings, both
/// files, the start-up plan). `Ok(None)` when no file is named (the sim backend needs
/// none); `Ok(Some(text))` describes the plan; `Err` is the one-line refusal.
pub fn check_config(cfg: &RigConfig, config: &Path) -> Result<Option<String>, String> {
    let c = &cfg.canopen;
    if c.transducer_eds.is_empty() && c.valve_eds.is_empty() && c.devices.is_empty() {
        return Ok(None);
    }
    // Never opened: the checks before the bus need no bus, only a valid address.
    let url = BusUrl::SocketCan {
        iface: "can0".into(),
    };
    let plan = CanopenHal::check_settings(&settings(cfg, config, url, false))
        .map_err(|e| e.to_string())?;
    let devices: Vec<String> = plan
        .devices
        .iter()
        .map(|d| {
            format!(
                "{} {} ({} start-up steps)",
                d.device.name(),
                d.eds.source,
                d.steps.len()
            )
        })
        .collect();
    Ok(Some(format!("canopen: {}", devices.join(", "))))
}

/// The CAN rig of `--hal canopen`, unconfigured (no bus I/O yet); `Ok(None)` for the sim
/// backend. The session brings it up ([`ehactl_runtime::session::run_realtime`]: configure,
/// then activate; may block up to `canopen.boot_timeout_s`); `stop` (SIGINT / SIGTERM) ends
/// that start-up within one master heartbeat period, the valve back to HOLD if it was being
/// enabled. `json`: no start-up progress on stderr.
pub fn backend(
    cfg: &RigConfig,
    config: &Path,
    hal_bus: (HalKind, Option<&str>),
    json: bool,
    stop: &Arc<AtomicBool>,
) -> Result<Option<CanopenHal>, ExitCode> {
    Ok(bus_url(hal_bus)?
        .map(|url| CanopenHal::new_until(settings(cfg, config, url, !json), Some(stop.clone()))))
}

/// The exit of a failed start-up ([`SessionError::Startup`]): the reason on stderr; a
/// settings error exits 2 (nothing was logged); otherwise the session logged the attempt to
/// `out` (the frames on `/can`, a trip on `/events`, the reason in `/summary`, printed on
/// stdout with `json`) and the exit code is 4, or 130 when a signal stopped the start-up
/// (logged as interrupted, no trip).
///
/// [`SessionError::Startup`]: ehactl_runtime::session::SessionError::Startup
pub fn startup_failed(f: &FailedStartup, out: &Path, json: bool) -> ExitCode {
    eprintln!("ehactl: {}", f.report.reason);
    if f.report.settings_error {
        return ExitCode::from(2);
    }
    match &f.log {
        Ok(Some(summary)) => {
            eprintln!("ehactl: start-up attempt logged to {}", out.display());
            if json {
                println!("{summary}");
            }
        }
        Ok(None) => {}
        Err(e) => eprintln!("ehactl: {e}"),
    }
    ExitCode::from(if f.report.stopped {
        EXIT_STOPPED
    } else {
        EXIT_STARTUP
    })
}

/// Human-readable CAN lines of the run summary (nothing for the sim backend).
pub fn print_summary(summary: &serde_json::Value) {
    let Some(load) = summary["bus_load_percent"].as_f64() else {
        return;
    };
    println!(
        "  can bus       {} — load {:.1} % worst case ({:.0} µs per SYNC at {} Hz), start-up {:.2} s",
        summary["bus"].as_str().unwrap_or("?"),
        load,
        summary["bus_time_per_sync_us"].as_f64().unwrap_or(f64::NAN),
        summary["sync_rate_hz"],
        summary["startup_s"].as_f64().unwrap_or(f64::NAN)
    );
    println!(
        "  can frames    {} SYNC, {} rx, {} tx, {} wrong DLC, {} unknown COB-ID, valve {}",
        summary["syncs_sent"],
        summary["can_rx_frames"],
        summary["can_tx_frames"],
        summary["can_wrong_dlc"],
        summary["can_unknown_cob_id"],
        summary["valve_state"].as_str().unwrap_or("?")
    );
    if let Some(s) = summary["safe_stop"].as_str() {
        println!("  safe stop     {s}");
    }
}
