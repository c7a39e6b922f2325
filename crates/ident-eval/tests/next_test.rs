//! The next test (`ehactl_ident::nexttest`) played on the independent generator
//! (`crates/ident-eval/src/indep.rs`, equations written apart from `crates/plant`), and the
//! detection limits checked there (DIAGNOSIS.md "The next test", "Detection limits").
//!
//! The experiment loop: a case of a look-alike pair, the test proposed to separate the pair
//! made from its record, played on the generator with the same draws (hidden effect, nominal
//! errors), and both records diagnosed together (`--data` the new one, `--validate` the
//! original): the hidden effect must be the cause. And a small effect below its stated limit
//! under the test proposed to tighten that limit: the limit falls. The expected names are the
//! generator's.

use ehactl_config::RigConfig;
use ehactl_ident::{diagnose, nexttest, Diagnosis, Options};
use ehactl_ident_eval::indep::{
    make_case, make_case_driven, make_case_small, make_case_small_driven, Case,
};
use ehactl_plant::EffectId;

const DT: f64 = 1e-3;

fn opts(case: &Case) -> Options {
    Options {
        drive: case.drive,
        ..Options::default()
    }
}

/// Diagnose case `seed` `kind` alone, then with the test that separates `a` from `b` played
/// on the generator (the same draws); both diagnoses returned.
fn loop_once(seed: u64, kind: &str, a: EffectId, b: EffectId) -> (Diagnosis, Diagnosis) {
    let case = make_case(seed, kind, 1.5, DT).expect("case");
    let alone = diagnose(&case.nominal, &case.record, None, &opts(&case)).expect("alone");
    let t = nexttest::separating(a, b, &case.record);
    let u = nexttest::samples(&t, DT);
    let new = make_case_driven(seed, kind, &u, DT).expect("the proposed test runs on the rig");
    let both =
        diagnose(&case.nominal, &new.record, Some(&case.record), &opts(&case)).expect("both");
    eprintln!(
        "{seed} {kind}: alone `{}` ({}), with the next test ({:?}) `{}` ({}; {:?})",
        alone.cause, alone.status, t.excitation, both.cause, both.status, both.ambiguities
    );
    (alone, both)
}

/// Pair 1: a spool overlap (dead band) and a supply drop, both sides, with the large-level
/// test (small and large commands in one run).
#[test]
fn deadband_vs_supply_drop_is_named_with_the_next_test() {
    use EffectId::{SupplyPressureDrop as S, ValveDeadband as D};
    let (_, both) = loop_once(7002, "overlap", D, S);
    assert_eq!(both.cause, "valve_deadband", "{}", both.summary);
    let (_, both) = loop_once(7018, "supply_resistance", D, S);
    assert_eq!(both.cause, "supply_pressure_drop", "{}", both.summary);
}

/// Pair 2: lumped lines and a load-side mount, both sides, with the wide-band test.
#[test]
fn line_vs_mount_is_named_with_the_next_test() {
    use EffectId::{FlexibleMount as M, LineDynamics as L};
    let (_, both) = loop_once(7013, "lines", L, M);
    assert_eq!(both.cause, "line_dynamics", "{}", both.summary);
    let (_, both) = loop_once(7014, "load_mount", L, M);
    assert_eq!(both.cause, "flexible_mount", "{}", both.summary);
}

/// The small overlap of `bench/indep_small_cases.txt` 7303 (at 4× the noise, answered `none`,
/// below its stated limit) under the test proposed to tighten the dead band's limit, at the
/// same effect size: the effect now shows (the answer leaves `none`), but the limit does not
/// fall. With the linearised limits it fell 5.6× (1.95e-3 → 3.46e-4 of the spool stroke);
/// checked by injection (DIAGNOSIS.md "Detection limits"), the new record's limit is
/// raised (1.8e-2: a dead band the size of the hidden one, 8.9e-4, is not accepted on it, and
/// the step up is coarse) while the original's 1.95e-3 is confirmed. A documented miss: this
/// asserts the miss, and fails when the next test lowers the checked limit again.
#[test]
fn the_dead_band_limit_under_the_next_test() {
    let case = make_case_small(7303, "overlap", 4.0, 1.5, DT).expect("case");
    let alpha = ehactl_ident_eval::limscore::alpha_from_source(&case.record.source).expect("α");
    let d0 = diagnose(&case.nominal, &case.record, None, &opts(&case)).expect("alone");
    let t = nexttest::tightening(EffectId::ValveDeadband, &case.record);
    let u = nexttest::samples(&t, DT);
    let new = make_case_small_driven(7303, "overlap", alpha, &u, DT).expect("runs");
    let d1 = diagnose(&case.nominal, &new.record, None, &opts(&case)).expect("new");
    let limit = |d: &Diagnosis| {
        d.detection_limits
            .get("valve_deadband")
            .and_then(|l| l.limit)
    };
    eprintln!(
        "7303: `{}` limit {:?}; with the next test `{}` limit {:?}",
        d0.cause,
        limit(&d0),
        d1.cause,
        limit(&d1)
    );
    assert_eq!(d0.cause, "none", "{}", d0.summary);
    assert_ne!(d1.cause, "none", "{}", d1.summary);
    let before = limit(&d0).expect("a limit on the original");
    if let Some(after) = limit(&d1) {
        assert!(
            after >= before,
            "the next test lowers the checked limit now ({after} vs {before}): assert that again"
        );
    }
}

/// Every proposed section is playable: put in place of the test bench's `[setpoint]`, the
/// config validates (`ehactl run`'s own check) and its generator gives the samples the
/// experiment loop plays.
#[test]
fn the_proposed_sections_are_what_ehactl_run_plays() {
    let case = make_case(7002, "overlap", 1.5, DT).expect("case");
    let text = ehactl_ident_eval::synth::TESTRIG_TOML;
    let start = text.find("[setpoint]").expect("a setpoint section");
    let end = start + text[start..].find("\n[run]").expect("a run section");
    for (a, b) in [
        (EffectId::ValveDeadband, EffectId::SupplyPressureDrop),
        (EffectId::LineDynamics, EffectId::FlexibleMount),
        (EffectId::Friction, EffectId::ValveDeadband),
        (EffectId::InternalLeakage, EffectId::ExternalLeakage),
    ] {
        let t = nexttest::separating(a, b, &case.record);
        let toml = format!(
            "{}{}{}",
            &text[..start],
            nexttest::toml_text(&t),
            &text[end..]
        );
        let cfg = RigConfig::from_toml_str(&toml)
            .unwrap_or_else(|e| panic!("{a:?}/{b:?}: {e}\n{}", nexttest::toml_text(&t)));
        assert_eq!(cfg.setpoint, t.setpoint);
        let sp = ehactl_control::setpoint::Setpoint::new(&cfg.setpoint);
        let u = nexttest::samples(&t, DT);
        assert_eq!(u.len(), (t.duration / DT).round() as usize);
        for (k, v) in u.iter().enumerate().step_by(97) {
            assert_eq!(*v, sp.sample(k as f64 * DT).0);
        }
        // Inside the record's own command range (its 2nd–98th percentile span, here ±10 V).
        assert!(u.iter().all(|v| v.abs() <= 10.0), "{a:?}/{b:?}");
    }
}

/// On a clean record of the generator (its rich multisine on random levels excites every
/// static and dynamic effect of the catalogue up to 35 Hz), each limit is finite and inside
/// the catalogue range searched, for every effect the record excites: all but the sensor
/// tone (no residual line: not testable on a clean record).
#[test]
fn limits_are_finite_and_inside_the_range_on_a_clean_generator_record() {
    let case = make_case(7020, "clean", 1.5, DT).expect("case");
    let d = diagnose(&case.nominal, &case.record, None, &opts(&case)).expect("diagnosis");
    assert_eq!(d.cause, "none", "{}", d.summary);

    for (e, l) in &d.detection_limits {
        eprintln!(
            "{e}: {:?} {} range {:?} ({})",
            l.limit, l.unit, l.range, l.note
        );
        if e == "sensor_tone" {
            continue;
        }
        match l.limit {
            Some(v) => {
                assert!(v.is_finite(), "{e}: {v}");
                let (lo, hi) = (l.range[0].min(l.range[1]), l.range[0].max(l.range[1]));
                assert!(
                    v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9),
                    "{e}: {v} outside {:?}",
                    l.range
                );
            }
            None => panic!("{e}: no limit ({})", l.note),
        }
    }
    assert!(
        d.detection_limits.len() >= 10,
        "{:?}",
        d.detection_limits.keys()
    );
}
