//! Run-path defects found by review and fuzzing, each reproduced as it was found: config values that passed
//! validation and then tripped (or crawled) at run time, live `set` values that were
//! accepted although absurd, and a loop that ran bang-bang at ±10 V without a trip.

use ehactl_config::RigConfig;
use ehactl_runtime::live::{self, LiveParams};
use ehactl_runtime::session::{run_sim, run_sim_live, SessionOptions};
use ehactl_tests::{config, repo};
use std::sync::Arc;
use std::time::Duration;

fn text(name: &str) -> String {
    std::fs::read_to_string(repo().join("configs").join(name)).unwrap()
}

fn err_of(text: &str) -> String {
    match RigConfig::from_toml_str(text) {
        Ok(c) => match ehactl_runtime::session::build_plant(&c) {
            Ok(p) => panic!(
                "config should be rejected; it builds with {} substeps",
                p.substeps()
            ),
            Err(e) => e.to_string(),
        },
        Err(e) => e.to_string(),
    }
}

fn replace(text: &str, old: &str, new: &str) -> String {
    assert!(text.contains(old), "`{old}` not in config");
    text.replacen(old, new, 1)
}

#[test]
fn min_position_above_max_position_is_a_config_error() {
    let t = replace(
        &text("dindorf2022_boom.toml"),
        "min_position = -0.01",
        "min_position = 2.0",
    );
    let e = err_of(&t);
    assert!(
        e.contains("`supervisor.min_position`") && e.contains("below max_position"),
        "{e}"
    );
}

#[test]
fn a_line_of_absurd_diameter_is_refused_not_run_at_100000_substeps() {
    let t = text("sirohi2003_lines.toml");
    let line = t
        .lines()
        .find(|l| l.trim_start().starts_with("diameter"))
        .expect("diameter line");
    let e = err_of(&t.replacen(line, "diameter = 1e308", 1));
    assert!(
        e.contains("`effects.line_dynamics.diameter`") && e.contains("m"),
        "{e}"
    );
}

#[test]
fn substeps_beyond_the_cap_name_the_reason() {
    // A plausible-looking but extremely stiff rig: 1e-12 m³ dead volumes on Sirohi 2003's lines.
    let t = text("sirohi2003_lines.toml");
    let t = t
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("dead_volume_") {
                format!("{} = 1.0e-15", l.split('=').next().unwrap().trim())
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let e = err_of(&t);
    assert!(
        e.contains("`integration.substeps`") && e.contains("rad/s") && e.contains("at most"),
        "{e}"
    );
}

#[test]
fn absurd_valve_natural_frequency_is_refused() {
    let t = replace(
        &text("sahu2022_force.toml"),
        "natural_frequency = 1507.9",
        "natural_frequency = 1e308",
    );
    let e = err_of(&t);
    assert!(
        e.contains("`effects.valve_dynamics.natural_frequency`") && e.contains("rad/s"),
        "{e}"
    );
}

#[test]
fn nyquist_error_names_the_field_that_is_too_high() {
    // f0 above Nyquist, f1 fine: the message used to blame f1.
    let t = replace(&text("sahu2022_force.toml"), "f0 = ", "f0 = 4000.0\n#");
    let e = err_of(&t);
    assert!(e.contains("`setpoint.f0`") && e.contains("Nyquist"), "{e}");
}

#[test]
fn setpoint_outside_the_stroke_or_force_capacity_is_refused() {
    let t = replace(&text("dindorf2022_boom.toml"), "final = 0.6", "final = 5.0");
    let e = err_of(&t);
    assert!(
        e.contains("`setpoint.final`") && e.contains("stroke"),
        "{e}"
    );
    let t = replace(
        &text("sahu2022_force.toml"),
        "offset = 785.0",
        "offset = 1e12",
    );
    let e = err_of(&t);
    assert!(e.contains("`setpoint.offset`") && e.contains("N"), "{e}");
}

#[test]
fn pi_limits_beyond_the_valve_range_are_refused() {
    let t = replace(
        &text("sahu2022_force.toml"),
        "u_min = -10.0",
        "u_min = -1e9",
    );
    let e = err_of(&t);
    assert!(
        e.contains("`control.pi.u_min`") && e.contains("command_full_scale"),
        "{e}"
    );
}

/// Every value the probe got an `ok` for is now refused by the same checks as the config,
/// and the running config is left as it was.
#[test]
fn live_set_refuses_what_the_config_refuses() {
    let cfg0 = config("sahu2022_force.toml");
    for (path, v, expect) in [
        ("control.pi.kp", 1e9, "control.pi.kp"),
        ("control.pi.integral", 1e300, "control.pi.integral"),
        ("control.pi.u_max", 1e9, "control.pi.u_max"),
        ("control.pi.u_min", 5.0, "u_min"),
        ("setpoint.offset", 1e12, "setpoint.offset"),
    ] {
        let mut cfg = cfg0.clone();
        let mut assignments = vec![(path, v)];
        if path == "control.pi.u_min" {
            assignments.push(("control.pi.u_max", 4.0)); // u_min 5 > u_max 4
        }
        let e = live::prepare(&mut cfg, &assignments)
            .err()
            .unwrap_or_else(|| panic!("{path}={v} was accepted"));
        assert!(e.to_string().contains(expect), "{path}={v}: {e}");
        assert_eq!(
            cfg, cfg0,
            "a refused change must leave the running config alone"
        );
    }
    // A sane change still passes.
    let mut cfg = cfg0.clone();
    live::prepare(&mut cfg, &[("control.pi.kp", 0.4)]).unwrap();
}

/// Sahu 2022's config with the saturation watch `window` (s; None: off) and the
/// following-error watch out of the way (a 1e9 N bound), so that these tests see the
/// saturation watch alone.
fn sahu_watching_saturation(window: Option<f64>) -> String {
    let t = replace(
        &text("sahu2022_force.toml"),
        "following_error = 600.0",
        "following_error = 1e9",
    );
    let shipped = "saturation_window = 0.05";
    match window {
        Some(w) => replace(&t, shipped, &format!("saturation_window = {w}")),
        None => replace(&t, shipped, ""),
    }
}

fn saturating_config(window: Option<f64>) -> RigConfig {
    // The 004 loop with 60× its proportional gain: unstable, it limit-cycles at ±10 V.
    let t = replace(&sahu_watching_saturation(window), "kp = 0.57", "kp = 34.2");
    RigConfig::from_toml_str(&t).unwrap()
}

fn opts(duration: f64) -> SessionOptions<'static> {
    SessionOptions {
        duration: Some(duration),
        mcap: None,
        capture: true,
        ..Default::default()
    }
}

#[test]
fn sustained_saturation_trips_when_watched_and_only_then() {
    // Without the watch the loop rattles between the limits for the whole run (the defect).
    let s = run_sim(&saturating_config(None), opts(0.5)).unwrap();
    assert!(s.outcome.trip.is_none());
    let at_limit = s
        .records
        .iter()
        .filter(|r| r.command.abs() >= 9.999)
        .count() as f64
        / s.records.len() as f64;
    assert!(at_limit > 0.5, "the test loop must saturate: {at_limit}");
    // With a 20 ms window it trips within a few windows, on `saturation`.
    let s = run_sim(&saturating_config(Some(0.02)), opts(0.5)).unwrap();
    let trip = s.outcome.trip.expect("saturation trip");
    assert_eq!(trip.kind.as_str(), "saturation");
    assert!(trip.t < 0.2, "tripped late: {} s", trip.t);
    // The nominal loop with the same watch runs through.
    let t = sahu_watching_saturation(Some(0.02));
    let s = run_sim(&RigConfig::from_toml_str(&t).unwrap(), opts(0.5)).unwrap();
    assert!(s.outcome.trip.is_none(), "{:?}", s.outcome.trip);
}

/// A live gain change that drives the loop into saturation trips it (the probe's 38 s of
/// bang-bang at ±10 V). The change is published before the run starts and taken by the loop
/// through the live slot at its first cycle boundary: published from a thread during the run,
/// it raced the simulation (2 s of plant time take a few milliseconds) and, under load, came
/// after the run had ended.
#[test]
fn a_live_change_into_saturation_is_caught() {
    let t = sahu_watching_saturation(Some(0.02));
    let cfg = RigConfig::from_toml_str(&t).unwrap();
    let live = Arc::new(LiveParams::new());
    let seq = {
        let mut cfg = cfg.clone();
        let u = live::prepare(&mut cfg, &[("control.pi.kp", 34.2)]).unwrap();
        live.publish(u, Duration::from_secs(5)).unwrap()
    };
    let s = run_sim_live(&cfg, opts(2.0), Some(&live)).unwrap();
    let applied = live
        .wait_applied(seq, Duration::ZERO)
        .expect("the loop applied the live change");
    let trip = s
        .outcome
        .trip
        .expect("saturation trip after the live change");
    assert_eq!(trip.kind.as_str(), "saturation");
    let period = cfg.timebase().period();
    assert!(
        trip.t >= applied as f64 * period,
        "tripped at {} s, before the change took effect at cycle {applied}",
        trip.t
    );
}
