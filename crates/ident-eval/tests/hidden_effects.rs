//! Acceptance tests of `ehactl diagnose`: records made by the plant with a hidden effect (seeded draw of
//! its parameters from a realistic range, sensor noise, nominal config lacking the effect and
//! with ±10 % errors in valve gain, β₀, mass, damping and spring rate). `diagnose` must name the
//! hidden effect and cut the held-out NRMSE by at least 50 %; with nothing hidden it must say
//! `none`. Seeds are fixed (1000 + catalogue index), not chosen after looking at results.

use ehactl_ident::{diagnose, Options};
use ehactl_ident_eval::synth::{self, make_case};
use ehactl_plant::EffectId;

fn check(seed: u64, hidden: &[EffectId]) {
    let case = make_case(seed, hidden, 2.0);
    let d = diagnose(&case.nominal.plant, &case.record, None, &Options::default())
        .expect("diagnosis runs");
    let names: Vec<&str> = hidden.iter().map(|e| e.as_str()).collect();
    let report = format!(
        "seed {seed}, hidden {names:?}: causes {:?}, held-out NRMSE {:.4} → {:.4} (gain {:.1} %), floor {:.4}\n{}",
        d.causes, d.nrmse_nominal.overall, d.nrmse_extended.overall, d.gain * 100.0, d.noise_floor, d.summary
    );
    assert_eq!(
        d.candidates.len(),
        EffectId::ALL.len(),
        "every catalogue effect is a candidate: {report}"
    );
    if hidden.is_empty() {
        assert_eq!(d.cause, "none", "{report}");
        return;
    }
    for n in &names {
        assert!(
            d.causes.iter().any(|c| c == n),
            "hidden `{n}` not named: {report}"
        );
    }
    assert!(
        names.contains(&d.cause.as_str()),
        "top cause is not a hidden effect: {report}"
    );
    assert!(
        d.gain >= 0.5,
        "held-out NRMSE fell by less than 50 %: {report}"
    );
}

macro_rules! hidden {
    ($name:ident, $e:expr) => {
        #[test]
        fn $name() {
            let i = EffectId::ALL.iter().position(|x| *x == $e).unwrap() as u64;
            check(1000 + i, &[$e]);
        }
    };
}

hidden!(finds_friction, EffectId::Friction);
hidden!(finds_valve_deadband, EffectId::ValveDeadband);
hidden!(finds_valve_saturation, EffectId::ValveSaturation);
hidden!(finds_valve_dynamics, EffectId::ValveDynamics);
hidden!(finds_internal_leakage, EffectId::InternalLeakage);
hidden!(finds_external_leakage, EffectId::ExternalLeakage);
hidden!(finds_bulk_modulus_pressure, EffectId::BulkModulusPressure);
hidden!(finds_line_dynamics, EffectId::LineDynamics);
hidden!(finds_flexible_mount, EffectId::FlexibleMount);
hidden!(finds_time_delay, EffectId::TimeDelay);
hidden!(finds_sensor_tone, EffectId::SensorTone);
hidden!(finds_supply_pressure_drop, EffectId::SupplyPressureDrop);

/// The structural variants of `synth::VARIANT_CASES` (seed 1100 + catalogue index): named
/// by id, the variant reported, and the held-out NRMSE halved.
fn check_variant(e: EffectId, variant: &str) {
    let i = EffectId::ALL.iter().position(|x| *x == e).unwrap() as u64;
    let seed = 1100 + i;
    let case = synth::make_case_variant(seed, e, variant, 2.0);
    let d = diagnose(&case.nominal.plant, &case.record, None, &Options::default())
        .expect("diagnosis runs");
    let report = format!(
        "seed {seed}, hidden {e} ({variant}): causes {:?}, variants {:?}, held-out NRMSE {:.4} → {:.4} (gain {:.1} %), floor {:.4}\n{}",
        d.causes, d.variants, d.nrmse_nominal.overall, d.nrmse_extended.overall, d.gain * 100.0, d.noise_floor, d.summary
    );
    eprintln!("{report}");
    assert!(d.causes.iter().any(|c| c == e.as_str()), "{report}");
    assert_eq!(d.cause, e.as_str(), "{report}");
    assert_eq!(
        d.variants.get(e.as_str()).map(String::as_str),
        Some(variant),
        "{report}"
    );
    assert!(d.gain >= 0.5, "{report}");
}

#[test]
fn finds_friction_lugre() {
    check_variant(EffectId::Friction, "lugre");
}

#[test]
fn finds_line_dynamics_hose() {
    check_variant(EffectId::LineDynamics, "hose");
}

#[test]
fn clean_data_gives_none() {
    check(2000, &[]);
}

#[test]
fn clean_data_gives_none_second_seed() {
    check(2001, &[]);
}

#[test]
fn two_effects_deadband_and_delay() {
    check(3000, &[EffectId::ValveDeadband, EffectId::TimeDelay]);
}

#[test]
fn two_effects_internal_leakage_and_tone() {
    check(3001, &[EffectId::InternalLeakage, EffectId::SensorTone]);
}

/// A pair the evaluation missed (case seed 5098 of `examples/evaluate.rs`, taken from its
/// list of misses, not fixed in advance): a load-side mount hidden with valve dynamics. The
/// mount's variant used to be chosen in round 0, with the valve dynamics still unexplained,
/// where `piston_side` won; on top of `valve_dynamics` that variant explained 6 % of what was
/// left and only `valve_dynamics` was named. Later rounds now refit every variant.
#[test]
fn two_effects_mount_and_valve_dynamics() {
    check(5098, &[EffectId::FlexibleMount, EffectId::ValveDynamics]);
}

/// Robustness to sensor offsets (`Options::sensor_offsets`, CLI
/// `--sensor-offsets`). Constant zero errors on every channel
/// (`synth::realistic_offsets`: +2 / −1.5 bar, 5 % of the force's std, +0.5 mm) must not
/// change the decision or the held-out errors, and the offsets the diagnosis estimates must
/// move by exactly what was added (the estimate itself also carries the model's own mean
/// error, which is the same with and without the zero errors).
#[test]
fn sensor_offsets_change_nothing() {
    let clean = make_case(4000, &[EffectId::Friction], 2.0);
    let mut shifted = clean.record.clone();
    let added = synth::realistic_offsets(&shifted);
    synth::add_sensor_offsets(&mut shifted, &added);
    let opts = Options {
        sensor_offsets: true,
        ..Options::default()
    };
    let a = diagnose(&clean.nominal.plant, &clean.record, None, &opts).unwrap();
    let b = diagnose(&clean.nominal.plant, &shifted, None, &opts).unwrap();
    assert_eq!(a.causes, b.causes);
    assert!(a.causes.iter().any(|c| c == "friction"), "{:?}", a.causes);
    let rel = |x: f64, y: f64| (x - y).abs() / x.abs().max(1e-12);
    assert!(
        rel(a.nrmse_extended.overall, b.nrmse_extended.overall) < 0.02,
        "{} vs {}",
        a.nrmse_extended.overall,
        b.nrmse_extended.overall
    );
    for (kind, off) in &added {
        let ch = kind.column();
        let moved = b.sensor_offsets[ch] - a.sensor_offsets[ch];
        assert!(
            rel(*off, moved) < 0.01,
            "{ch}: added {off:e}, estimate moved by {moved:e}"
        );
    }
}

/// The clean case of `clean_data_gives_none` with the same zero errors added: still `none`
/// with the offsets estimated, and trusting the zeros makes even the refit nominal model far
/// worse.
#[test]
fn sensor_offsets_alone_give_none() {
    let mut case = make_case(2000, &[], 2.0);
    let added = synth::realistic_offsets(&case.record);
    synth::add_sensor_offsets(&mut case.record, &added);
    let estimating = Options {
        sensor_offsets: true,
        ..Options::default()
    };
    let d = diagnose(&case.nominal.plant, &case.record, None, &estimating).unwrap();
    assert_eq!(d.cause, "none", "{}", d.summary);
    let trusting = Options::default();
    let t = diagnose(&case.nominal.plant, &case.record, None, &trusting).unwrap();
    assert!(t.sensor_offsets.is_empty());
    assert!(
        t.nrmse_refit.overall > 2.0 * d.nrmse_refit.overall,
        "trusting the zeros: refit NRMSE {} vs {} with offsets",
        t.nrmse_refit.overall,
        d.nrmse_refit.overall
    );
}
