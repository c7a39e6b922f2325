//! Each class of config error yields one message naming the field path and the expected
//! unit: missing field, wrong type, negative, non-finite, out of range, unknown effect id,
//! unknown field, syntax error, cross-field inconsistency.

use ehactl_config::RigConfig;
use ehactl_tests::repo;

fn base() -> String {
    std::fs::read_to_string(repo().join("configs/sahu2022_force.toml")).unwrap()
}

fn err_of(text: &str) -> String {
    match RigConfig::from_toml_str(text) {
        Ok(_) => panic!("config should be rejected"),
        Err(e) => e.to_string(),
    }
}

fn replace_line(text: &str, starts: &str, new: &str) -> String {
    let mut found = false;
    let out: Vec<String> = text
        .lines()
        .map(|l| {
            if !found && l.trim_start().starts_with(starts) {
                found = true;
                new.to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    assert!(found, "line {starts} not in config");
    out.join("\n")
}

#[test]
fn every_shipped_config_loads() {
    for entry in std::fs::read_dir(repo().join("configs")).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "toml") {
            RigConfig::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        }
    }
}

#[test]
fn missing_field_names_path_and_unit() {
    let e = err_of(&replace_line(&base(), "bulk_modulus =", ""));
    assert!(e.contains("`fluid.bulk_modulus`"), "{e}");
    assert!(e.contains("missing"), "{e}");
    assert!(e.contains("Pa"), "{e}");
}

#[test]
fn wrong_type_names_path_and_unit() {
    let e = err_of(&replace_line(&base(), "mass =", "mass = \"heavy\""));
    assert!(
        e.contains("`mechanics.mass`") && e.contains("kg") && e.contains("wrong type"),
        "{e}"
    );
}

#[test]
fn negative_physical_value_is_rejected() {
    let e = err_of(&replace_line(&base(), "area_a =", "area_a = -2.364e-4"));
    assert!(
        e.contains("`cylinder.area_a`") && e.contains("m²") && e.contains("> 0"),
        "{e}"
    );
}

#[test]
fn non_finite_value_is_rejected() {
    for v in ["nan", "inf", "-inf"] {
        let e = err_of(&replace_line(
            &base(),
            "pressure = 20.0e6",
            &format!("pressure = {v}"),
        ));
        assert!(
            e.contains("`supply.pressure`") && e.contains("not finite") && e.contains("Pa"),
            "{e}"
        );
    }
}

#[test]
fn unknown_effect_id_lists_the_catalogue() {
    let e = err_of(&format!(
        "{}\n[effects.valve_stiction]\ncoefficient = 1.0\n",
        base()
    ));
    assert!(
        e.contains("`effects.valve_stiction`") && e.contains("unknown effect id"),
        "{e}"
    );
    assert!(
        e.contains("friction") && e.contains("supply_pressure_drop"),
        "{e}"
    );
}

#[test]
fn unknown_field_is_named() {
    let e = err_of(&replace_line(
        &base(),
        "damping = 10.587",
        "dampign = 10.587",
    ));
    assert!(
        e.contains("`mechanics.dampign`") && e.contains("unknown field"),
        "{e}"
    );
}

#[test]
fn integer_for_float_is_accepted_and_integer_field_rejects_fraction() {
    let ok = replace_line(&base(), "control_rate_hz", "control_rate_hz = 5000");
    assert!(RigConfig::from_toml_str(&ok).is_ok());
    let e = err_of(&replace_line(&base(), "order = 2", "order = 1.5"));
    assert!(
        e.contains("`effects.valve_dynamics.order`") && e.contains("not an integer"),
        "{e}"
    );
}

#[test]
fn syntax_error_gives_line_and_column() {
    let e = err_of("[fluid\ndensity = 870.0\n");
    assert!(
        e.contains("line 1") && e.contains("TOML syntax error"),
        "{e}"
    );
}

#[test]
fn cross_field_errors_name_the_field() {
    let e = err_of(&replace_line(&base(), "rated_flow", ""));
    assert!(
        e.contains("`valve.rated_flow`") && e.contains("m³/s") && e.contains("kq"),
        "{e}"
    );
    let e = err_of(&replace_line(&base(), "f1 = 300.0", "f1 = 3000.0"));
    assert!(e.contains("`setpoint.f1`") && e.contains("Nyquist"), "{e}");
    let e = err_of(&replace_line(
        &base(),
        "amplitudes = [2.0, 2.0]",
        "amplitudes = [2.0]",
    ));
    assert!(e.contains("`effects.sensor_tone.amplitudes`"), "{e}");
    let e = err_of(&replace_line(
        &base(),
        "mode = \"force\"",
        "mode = \"position\"",
    ));
    assert!(e.contains("`control.pd`") && e.contains("V/m"), "{e}");
}

#[test]
fn out_of_range_value_is_rejected() {
    let e = err_of(&replace_line(&base(), "zero_offset", "zero_offset = 0.9"));
    assert!(
        e.contains("`effects.valve_deadband.zero_offset`") && e.contains("out of range"),
        "{e}"
    );
}

#[test]
fn config_round_trips_through_toml() {
    let cfg = RigConfig::from_toml_str(&base()).unwrap();
    let again = RigConfig::from_toml_str(&cfg.to_toml_string()).unwrap();
    assert_eq!(cfg, again);
}

/// A feed-forward gain has a physical range: 1.7e308 V/N (finite, formerly accepted) made
/// ff_term infinite and pinned the command at +10 V for a whole run without a trip.
#[test]
fn feedforward_gains_have_a_physical_range() {
    let text = base().replace("[control.pi]\n", "[control.pi]\nfeedforward = 1.7e308\n");
    let e = err_of(&text);
    assert!(
        e.contains("control.pi.feedforward") && e.contains("V/N"),
        "{e}"
    );
    let ok = base().replace("[control.pi]\n", "[control.pi]\nfeedforward = 1e-4\n");
    assert!(RigConfig::from_toml_str(&ok).is_ok());
}

/// A control-law term that is not finite trips the supervisor, naming the term, whatever
/// the config allowed (a live change, an integrator that overflowed).
#[test]
fn a_non_finite_control_term_trips() {
    use ehactl_control::pi::{Pi, PiGains};
    use ehactl_control::supervisor::{FeedbackChannel, Supervisor};
    let cfg = RigConfig::from_toml_str(&base()).unwrap();
    let mut sup = Supervisor::new(&cfg.supervisor, FeedbackChannel::Force);
    let mut pi = Pi::new(PiGains {
        kp: 0.5,
        integral: 300.0,
        error_scale: 5e-4,
        u_min: -10.0,
        u_max: 10.0,
        tracking: 0.0,
        feedforward: 1.7e308,
    });
    let terms = pi.step(2000.0, 0.0, 2e-4);
    assert_eq!(terms.u, 10.0, "the clamp hides the infinite term");
    let ev = sup.check_terms(0.0, 0, &terms).expect("a trip");
    assert_eq!(ev.channel, "ff_term");
    assert_eq!(ev.severity, ehactl_types::event::Severity::Trip);
    let fine = Pi::new(PiGains {
        feedforward: 1e-4,
        ..pi.gains
    })
    .step(2000.0, 0.0, 2e-4);
    assert!(sup.check_terms(0.0, 0, &fine).is_none());
}
