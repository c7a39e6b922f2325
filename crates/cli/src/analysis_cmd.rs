//! `ehactl analyze` and `ehactl sweep`.

use crate::{config_error, default_log_path, load, progress_bar, stop_flag};
use clap::Args;
use ehactl_analysis::sweep::{Channel, SweepOptions};
use ehactl_analysis::{analyze as run_analysis, sweep as run_sweep, AnalysisError};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `ehactl sweep`.
#[derive(Args)]
pub struct SweepArgs {
    /// Rig config (TOML).
    config: PathBuf,
    /// Lowest frequency (Hz); default the setpoint's f0 or 1 Hz.
    #[arg(long = "from", allow_negative_numbers = true)]
    from_hz: Option<f64>,
    /// Highest frequency (Hz); default the setpoint's f1 or a tenth of the control rate.
    #[arg(long = "to", allow_negative_numbers = true)]
    to_hz: Option<f64>,
    /// Number of log-spaced frequencies.
    #[arg(long, default_value_t = 30)]
    points: usize,
    /// Sine amplitude: N or m closed loop (default the setpoint's), V open loop.
    #[arg(long, allow_negative_numbers = true)]
    amplitude: Option<f64>,
    /// Open loop: sine on the valve command around the operating command.
    #[arg(long)]
    open_loop: bool,
    /// Output channel: force, position, p_a or p_b.
    #[arg(long)]
    output: Option<String>,
    /// Periods of the lowest frequency per dwell (≥ 6).
    #[arg(long, default_value_t = 6.0)]
    periods: f64,
    /// MCAP log (default out/<config name>_sweep.mcap closed loop,
    /// out/<config name>_sweep_open.mcap open loop).
    // The doc comment is clap's `--help` text, printed as written: `<config name>` is no
    // HTML tag.
    #[allow(rustdoc::invalid_html_tags)]
    #[arg(long)]
    out: Option<PathBuf>,
    /// Log one control cycle in N to the MCAP file (1 = every cycle); the estimate always
    /// uses every cycle.
    #[arg(long, value_name = "N", default_value_t = ehactl_analysis::sweep::DEFAULT_LOG_EVERY)]
    log_every: u64,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

fn fail(config: &Path, e: AnalysisError) -> ExitCode {
    match e {
        AnalysisError::Config(e) => config_error(format!("{}: {e}", config.display())),
        AnalysisError::Session(ehactl_runtime::session::SessionError::Config(e)) => {
            config_error(format!("{}: {e}", config.display()))
        }
        e => {
            eprintln!("ehactl: {}: {e}", config.display());
            ExitCode::from(1)
        }
    }
}

fn fmt_opt(v: Option<f64>, unit: &str) -> String {
    v.map_or("—".into(), |v| format!("{v:.2} {unit}"))
}

/// The operating point of `ehactl analyze` in words with units (the `--json` output keeps the
/// raw numbers): reference and feedback in the control mode's unit, command, piston position,
/// chamber pressures, rod force, and whether and when the loop came to rest.
fn operating_point_text(op: &serde_json::Value, mode: ehactl_config::ControlMode) -> String {
    use crate::sig;
    let num = |k: &str| op[k].as_f64().unwrap_or(f64::NAN);
    let unit = mode.unit();
    let x = num("position_m");
    let position = if x.abs() < 1e-3 {
        format!("{} µm", sig(x * 1e6, 4))
    } else {
        format!("{} m", sig(x, 4))
    };
    let rest = if op["settled"].as_bool().unwrap_or(false) {
        format!("at rest after {} s", sig(num("search_time_s"), 3))
    } else {
        format!("NOT at rest after {} s", sig(num("search_time_s"), 3))
    };
    format!(
        "reference {r} {unit}, feedback {f} {unit}, command {u} V, position {position}, p_A {pa} MPa, p_B {pb} MPa, rod force {fr} N ({rest})",
        r = sig(num("reference"), 5),
        f = sig(num("feedback"), 5),
        u = sig(num("command_V"), 4),
        pa = sig(num("p_a_Pa") * 1e-6, 4),
        pb = sig(num("p_b_Pa") * 1e-6, 4),
        fr = sig(num("rod_force_N"), 5),
    )
}

/// The stability verdict in words: stable with the largest closed-loop pole magnitude (and
/// the poles on the circle, if any), or UNSTABLE with the poles outside it (|z| and
/// frequency).
pub fn stability_text(st: &ehactl_analysis::analyze::Stability) -> String {
    use crate::sig;
    // A pole a hair off the circle reads 1 ± δ, not 1.
    let magnitude = |m: f64| {
        if (m - 1.0).abs() < 1e-3 {
            format!(
                "1 {} {:.2e}",
                if m < 1.0 { "−" } else { "+" },
                (m - 1.0).abs()
            )
        } else {
            sig(m, 4)
        }
    };
    if st.stable {
        let marginal = match st.marginal_poles.len() {
            0 => String::new(),
            n => format!(
                "; {n} on it within {:e}: modes the loop does not act on at this operating point",
                ehactl_analysis::analyze::ON_THE_CIRCLE
            ),
        };
        return format!(
            "stable (linearised sampled loop: no closed-loop pole outside the unit circle, largest |z| = {}{marginal})",
            magnitude(st.max_pole_magnitude)
        );
    }
    let poles: Vec<String> = st
        .unstable_poles
        .iter()
        .map(|p| {
            format!(
                "|z| = {} at {} Hz",
                magnitude(p.magnitude),
                sig(p.frequency_hz, 4)
            )
        })
        .collect();
    format!(
        "UNSTABLE (linearised sampled loop: closed-loop poles outside the unit circle: {})",
        poles.join(", ")
    )
}

/// `ehactl analyze CONFIG [--json]`.
pub fn analyze(config: &Path, json: bool) -> ExitCode {
    let cfg = match load(config) {
        Ok(c) => c,
        Err(code) => return code,
    };
    let a = match run_analysis(&cfg) {
        Ok(a) => a,
        Err(e) => return fail(config, e),
    };
    if json {
        println!("{}", a.to_json());
        return ExitCode::SUCCESS;
    }
    println!("ehactl analyze {} ({})", config.display(), a.rig);
    println!(
        "  operating point       {}",
        operating_point_text(&a.operating_point, cfg.control.mode)
    );
    println!(
        "  hydraulic ω_h         {:.2} Hz at the operating position; lowest over stroke {:.2} Hz at {:.3} m",
        a.hydraulic_natural_frequency_hz,
        a.min_natural_frequency_over_stroke_hz,
        a.min_natural_frequency_position_m
    );
    println!(
        "  open-loop bandwidth   {}",
        fmt_opt(a.open_loop_bandwidth_hz, "Hz")
    );
    if let Some(st) = &a.stability {
        println!("  stability             {}", stability_text(st));
    }
    let unstable = a.stability.as_ref().is_some_and(|s| !s.stable);
    for (name, m) in [
        ("sampled loop (ZOH)", &a.discrete),
        ("continuous loop", &a.continuous),
    ] {
        if let Some(m) = m {
            let closed = if unstable {
                "closed-loop bandwidth meaningless (unstable loop)".to_string()
            } else {
                format!(
                    "closed-loop bandwidth {} peak {:.2} dB",
                    fmt_opt(m.closed_loop_bandwidth_hz, "Hz"),
                    m.closed_loop_peak_db
                )
            };
            println!(
                "  {name:<21} crossover {} PM {} | phase crossover {} GM {} | {closed}",
                fmt_opt(m.gain_crossover_hz, "Hz"),
                fmt_opt(m.phase_margin_deg, "°"),
                fmt_opt(m.phase_crossover_hz, "Hz"),
                fmt_opt(m.gain_margin_db, "dB"),
            );
        }
    }
    if let Some(s) = &a.sdd {
        println!(
            "  SDD (003 eq. 23–29)   f_y {:.2} Hz, f_m {:.3} Hz, fr_ym {:.2}, fr_em {}, rd_my {:.2}",
            s.f_y_hz,
            s.f_m_hz,
            s.fr_ym,
            s.fr_em.map_or("—".into(), |v| format!("{v:.2}")),
            s.rd_my
        );
    }
    let poles: Vec<String> = a
        .poles
        .iter()
        .map(|p| format!("{:.1} Hz ζ {:.2}", p.frequency_hz, p.damping_ratio))
        .collect();
    println!("  slowest plant poles   {}", poles.join(", "));
    ExitCode::SUCCESS
}

/// `ehactl sweep CONFIG ...`.
pub fn sweep(args: &SweepArgs) -> ExitCode {
    let config = &args.config;
    let cfg = match load(config) {
        Ok(c) => c,
        Err(code) => return code,
    };
    let output = match args.output.as_deref().map(|s| (s, Channel::parse(s))) {
        None => None,
        Some((_, Some(c))) => Some(c),
        Some((s, None)) => {
            return config_error(format!(
                "--output {s}: expected one of force (N), position (m), p_a (Pa), p_b (Pa)"
            ))
        }
    };
    let out = args.out.clone().unwrap_or_else(|| {
        default_log_path(
            config,
            if args.open_loop {
                "_sweep_open"
            } else {
                "_sweep"
            },
        )
    });
    if args.log_every == 0 {
        return config_error("--log-every 0: expected an integer ≥ 1 (log one cycle in N)");
    }
    if let Err(code) = crate::check_log_path(&out, config, false) {
        return code;
    }
    let stop = stop_flag();
    let bar = progress_bar(format!("sweep {}", config.display()));
    let mut progress = |k: u64, n: u64| {
        bar.set_length(n);
        bar.set_position(k);
    };
    let result = run_sweep(
        &cfg,
        SweepOptions {
            from_hz: args.from_hz,
            to_hz: args.to_hz,
            points: args.points,
            amplitude: args.amplitude,
            open_loop: args.open_loop,
            output,
            periods: args.periods,
            mcap: Some(out),
            stop: Some(&stop),
            progress: Some(&mut progress),
            log_every: args.log_every,
        },
    );
    bar.finish_and_clear();
    let r = match result {
        Ok(r) => r,
        Err(e) => return fail(config, e),
    };
    if args.json {
        println!("{}", serde_json::to_value(&r).unwrap_or_default());
    } else {
        println!(
            "ehactl sweep {} — {}: {} → {}, offset {:.4}, amplitude {:.4}, {:.4} s per frequency",
            config.display(),
            r.mode,
            r.input,
            r.output,
            r.offset,
            r.amplitude,
            r.dwell_s
        );
        println!(
            "  {:>10} {:>10} {:>10} {:>10} {:>10}",
            "f [Hz]", "|H| [dB]", "∠H [°]", "γ²", "distortion"
        );
        for p in &r.points {
            println!(
                "  {:>10.3} {:>10.3} {:>10.2} {:>10.4} {:>10.4}",
                p.f_hz, p.mag_db, p.phase_deg, p.coherence, p.distortion
            );
        }
        println!("  -3 dB bandwidth: {}", fmt_opt(r.bandwidth_hz, "Hz"));
        if let Some(m) = &r.mcap {
            println!("  mcap: {m}");
        }
        if let Some(t) = &r.trip {
            println!("  TRIP: {t}");
        }
    }
    if r.trip.is_some() {
        ExitCode::from(3)
    } else if !r.complete {
        ExitCode::from(130)
    } else {
        ExitCode::SUCCESS
    }
}
