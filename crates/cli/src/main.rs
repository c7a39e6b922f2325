//! `ehactl`: closed-loop runs against the simulated plant, config checks, parameter lists.
//!
//! Exit codes: 0 run completed, 2 bad config or arguments, 3 supervisor trip,
//! 130 interrupted by a signal (log finalised), 1 any other failure (I/O).

mod diagnose;

use clap::{Parser, Subcommand};
use ehactl_controller::config::registries;
use ehactl_controller::session::{run_sim, SessionError, SessionOptions};
use ehactl_controller::RigConfig;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "ehactl",
    version,
    about = "Real-time electro-hydraulic actuator controller with a simulated plant"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a closed-loop test of CONFIG against the simulated plant and log it to MCAP.
    Run {
        /// Rig config (TOML).
        config: PathBuf,
        /// Override run.duration (s).
        #[arg(long, allow_negative_numbers = true)]
        duration: Option<f64>,
        /// MCAP output file (default: out/<config name>.mcap).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print exactly one JSON object with the summary on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Validate CONFIG and print what it sets up.
    CheckConfig {
        /// Rig config (TOML).
        config: PathBuf,
    },
    /// List every config parameter with its unit and meaning.
    Params,
    /// Find what the simulation of CONFIG gets wrong on measured data, name the cause from the
    /// effect catalogue, extend the model and measure the gain on held-out data.
    Diagnose {
        /// Nominal rig config (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Measured data: CSV (t, u, any of force, x, p_a, p_b, x_v, ref; SI) or an ehactl MCAP.
        #[arg(long)]
        data: PathBuf,
        /// Separate validation record (default: the last 30 % of --data is held out).
        #[arg(long)]
        validate: Option<PathBuf>,
        /// Output directory for extended.toml, report.md and plots.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print exactly one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
}

fn config_error(e: impl std::fmt::Display) -> ExitCode {
    eprintln!("ehactl: {e}");
    ExitCode::from(2)
}

fn load(path: &Path) -> Result<RigConfig, ExitCode> {
    RigConfig::load(path).map_err(|e| config_error(format!("{}: {e}", path.display())))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            config,
            duration,
            out,
            json,
        } => cmd_run(&config, duration, out, json),
        Command::CheckConfig { config } => {
            let cfg = match load(&config) {
                Ok(c) => c,
                Err(code) => return code,
            };
            match ehactl_controller::session::build_plant(&cfg) {
                Ok(plant) => {
                    println!(
                        "{}: ok — mode {:?}, {} Hz control, {} substeps of {:.3} µs, effects: [{}]",
                        config.display(),
                        cfg.control.mode,
                        cfg.run.control_rate_hz,
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
                    ExitCode::SUCCESS
                }
                Err(e) => config_error(format!("{}: {e}", config.display())),
            }
        }
        Command::Diagnose {
            config,
            data,
            validate,
            out,
            json,
        } => diagnose::cmd_diagnose(&config, &data, validate.as_deref(), out, json),
        Command::Params => {
            for table in registries() {
                for p in table {
                    println!("{:<48} {:<12} {}", p.path, p.unit, p.description);
                }
            }
            ExitCode::SUCCESS
        }
    }
}

fn cmd_run(config: &Path, duration: Option<f64>, out: Option<PathBuf>, json: bool) -> ExitCode {
    let cfg = match load(config) {
        Ok(c) => c,
        Err(code) => return code,
    };
    if let Some(d) = duration {
        if !(d.is_finite() && d > 0.0) {
            return config_error(format!("--duration {d}: expected a finite number > 0 in s"));
        }
    }
    let out = out.unwrap_or_else(|| {
        let stem = config
            .file_stem()
            .map_or("run".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from("out").join(format!("{stem}.mcap"))
    });
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        if let Err(e) = signal_hook::flag::register(sig, stop.clone()) {
            eprintln!("ehactl: warning: cannot install signal handler: {e}");
        }
    }
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} {msg} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(format!("{} (simulated)", config.display()));
    let mut progress = |k: u64, n: u64| {
        bar.set_length(n);
        bar.set_position(k);
    };
    let result = run_sim(
        &cfg,
        SessionOptions {
            duration,
            mcap: Some(out),
            stop: Some(&stop),
            capture: false,
            progress: Some(&mut progress),
        },
    );
    bar.finish_and_clear();
    let session = match result {
        Ok(s) => s,
        Err(SessionError::Config(e)) => return config_error(format!("{}: {e}", config.display())),
        Err(e) => {
            eprintln!("ehactl: {e}");
            return ExitCode::from(1);
        }
    };
    let summary = session.summary_json();
    if json {
        println!("{summary}");
    } else {
        let o = &session.outcome;
        println!("ehactl run {}", config.display());
        println!(
            "  cycles        {} at {} Hz ({} s simulated, {} substeps/cycle)",
            o.cycles, session.control_rate_hz, o.duration_s, session.substeps
        );
        println!(
            "  rms error     {:.6e} {} (after start of dynamics: {:.6e})",
            o.rms_error, session.unit, o.rms_error_settled
        );
        println!("  max |error|   {:.6e} {}", o.max_abs_error, session.unit);
        println!(
            "  speed         {:.1}× real time ({:.3} s wall)",
            summary["sim_speed_x_realtime"].as_f64().unwrap_or(0.0),
            session.wall_time_s
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
        match (&o.trip, o.interrupted) {
            (Some(t), _) => println!("  TRIP          {}", t.describe()),
            (None, true) => {
                println!("  interrupted by signal; valve set to safe command, log finalised")
            }
            _ => println!("  trip          none"),
        }
    }
    if session.outcome.trip.is_some() {
        ExitCode::from(3)
    } else if session.outcome.interrupted {
        ExitCode::from(130)
    } else {
        ExitCode::SUCCESS
    }
}
