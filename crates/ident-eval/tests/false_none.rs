//! `none` means noise. A record of the test bench made with the config's own plant (so the
//! configured-step shortcut may answer `none`) must be answered `none`; the same record with
//! one catalogue effect added at a small magnitude — its residual 2–3× the noise floor on the
//! channel it moves most — must not be: such a residual is coloured (thousands of Ljung–Box
//! units from white), and a level test alone once took it for noise.
//!
//! The small magnitude is made from the effect's own output difference: the record of the
//! plant with the effect (parameters drawn as in the catalogue tests) minus the clean record,
//! both with the same sensor noise, scaled so that the largest channel's residual sits at
//! 2.5× its sensor noise, and added to the clean record. To first order that is the effect at
//! a smaller parameter; it keeps the effect's signature (band, dependence, lag) exactly.

use ehactl_ident::data::Record;
use ehactl_ident::{diagnose, Options};
use ehactl_ident_eval::synth::{self, excitation, simulate, testrig, Rng};
use ehactl_plant::EffectId;

const DT: f64 = 1e-3;
const SECONDS: f64 = 2.0;
/// Target level of the added residual over the sensor noise on its largest channel (-).
const LEVEL: f64 = 2.5;

fn clean(seed: u64) -> Record {
    let mut p = testrig().plant;
    p.sensors.seed = seed;
    let u = excitation(seed, DT, (SECONDS / DT).round() as usize);
    simulate(&p, &u, DT, &format!("clean seed {seed}"))
}

/// The clean record of `seed` with effect `e` added at [`LEVEL`] × the sensor noise.
fn with_small(seed: u64, e: EffectId) -> (Record, f64) {
    let base = clean(seed);
    let mut p = testrig().plant;
    p.sensors.seed = seed;
    synth::hide(e, &mut p, &mut Rng::new(seed));
    let full = simulate(&p, &base.u, DT, "full effect");
    let (mut rec, alpha) = synth::small_effect(&base, &full, LEVEL, synth::testrig_noise)
        .unwrap_or_else(|| panic!("{e:?} changes no channel"));
    rec.source = format!("seed {seed}, {} at {LEVEL}× the noise", e.as_str());
    (rec, alpha)
}

#[test]
fn own_clean_record_is_none_by_the_shortcut() {
    for seed in [3000, 3001] {
        let d = diagnose(&testrig().plant, &clean(seed), None, &Options::default()).unwrap();
        assert_eq!(d.cause, "none", "seed {seed}: {}", d.summary);
        assert!(
            d.integration.configured_step_explains,
            "seed {seed}: the shortcut did not accept the config's own plant: {}",
            d.summary
        );
    }
}

/// The diagnosis of effect `e` added small to a clean record, and a one-line account of it.
fn diagnose_small(e: EffectId) -> (ehactl_ident::Diagnosis, String) {
    let seed = 3100 + EffectId::ALL.iter().position(|x| *x == e).unwrap() as u64;
    let (rec, alpha) = with_small(seed, e);
    let d = diagnose(&testrig().plant, &rec, None, &Options::default()).unwrap();
    let report = format!(
        "{} (α = {alpha:.3}): cause {}, causes {:?}, configured step explains {}\n{}",
        e.as_str(),
        d.cause,
        d.causes,
        d.integration.configured_step_explains,
        d.summary
    );
    (d, report)
}

/// The failure an outside generator found: the configured-step shortcut must not accept a
/// record with a real effect whose residual is coloured, whatever its level.
#[test]
fn no_small_effect_passes_the_shortcut() {
    for e in EffectId::ALL {
        let (d, report) = diagnose_small(e);
        assert!(!d.integration.configured_step_explains, "{report}");
    }
}

/// After the full search the answer must not be `none` either.
fn check_small(e: EffectId) {
    let (d, report) = diagnose_small(e);
    assert_ne!(d.cause, "none", "{report}");
}

/// One test per effect: `check` (the default or the known nominal) on effect `e`; with a
/// reason, an ignored known miss.
macro_rules! small {
    ($name:ident, $e:expr) => {
        small!($name, $e, check_small);
    };
    ($name:ident, $e:expr, $check:ident) => {
        #[test]
        fn $name() {
            $check($e);
        }
    };
    ($name:ident, $e:expr, $check:ident, $why:literal) => {
        #[test]
        #[ignore = $why]
        fn $name() {
            $check($e);
        }
    };
}

// Found at 2.5× the noise (2026-11-28):
small!(
    small_external_leakage_is_not_none,
    EffectId::ExternalLeakage
);
small!(small_sensor_tone_is_not_none, EffectId::SensorTone);
small!(
    small_supply_pressure_drop_is_not_none,
    EffectId::SupplyPressureDrop
);
small!(small_time_delay_is_not_none, EffectId::TimeDelay);
// Not `none` since the refit with restarts and `residual::LEVEL_SOFT` = 2.5 (2026-11-28): the
// residual is coloured above 2.5× its floor, so the answer is `unexplained` or the effect.
small!(
    small_internal_leakage_is_not_none,
    EffectId::InternalLeakage
);
small!(small_flexible_mount_is_not_none, EffectId::FlexibleMount);
// Known misses: after the full search no candidate passes the acceptance and the residual,
// white or coloured below `residual::LEVEL_SOFT` = 2.5× its floor, is counted as noise
// (`none`). The soft level is calibrated on clean records (a clean PI force-rig record leaves
// 2.36×), so it cannot go lower without answering clean records `unexplained`; what would
// name these is an acceptance that weighs the low-noise channels (DIAGNOSIS.md).
small!(
    small_friction_is_not_none,
    EffectId::Friction,
    check_small,
    "known miss: none at 2.5x the noise"
);
small!(
    small_valve_deadband_is_not_none,
    EffectId::ValveDeadband,
    check_small,
    "known miss: none at 2.5x the noise"
);
small!(
    small_valve_saturation_is_not_none,
    EffectId::ValveSaturation,
    check_small,
    "known miss: none at 2.5x the noise"
);
small!(
    small_valve_dynamics_is_not_none,
    EffectId::ValveDynamics,
    check_small,
    "known miss: none at 2.5x the noise"
);
small!(
    small_bulk_modulus_pressure_is_not_none,
    EffectId::BulkModulusPressure,
    check_small,
    "known miss: none at 2.5x the noise"
);
small!(
    small_line_dynamics_is_not_none,
    EffectId::LineDynamics,
    check_small,
    "known miss: none at 2.5x the noise"
);

/// An effect that shows only on the low-noise position channel: the test bench's evaluation
/// case 5117 (`evaluate -- 0 0 0 5112 OUT.md 0 3`, an external leak at 2× the sensor noise,
/// the nominal config ±10 % off). The refit leaves the position at 2.4× its floor and
/// coloured (Ljung–Box Q ≈ 6700) while the channel-mean J hardly sees it: the leak's fit lowered
/// it by < 2 % and the answer was `none`. On the floor-weighted J the leak explains most of the
/// error above the floor and is named, with the acceptance saying so in its evidence.
#[test]
fn an_effect_seen_on_the_position_channel_alone_is_named() {
    let (case, _) = synth::make_case_small(5117, EffectId::ExternalLeakage, 2.0, 2.0);
    let d = diagnose(&case.nominal.plant, &case.record, None, &Options::default()).unwrap();
    assert_eq!(d.cause, "external_leakage", "{}", d.summary);
    let c = d
        .candidates
        .iter()
        .find(|c| c.effect == "external_leakage")
        .expect("the leak was a candidate");
    assert!(c.accepted, "{}", c.evidence);
    assert!(
        c.evidence.contains("floor-weighted J"),
        "accepted on the floor-weighted J: {}",
        c.evidence
    );
}

/// The test bench's nominal stated as known: `[uncertainty]` 0 % on the five parameters the
/// diagnosis refits by default (DIAGNOSIS.md "Nominal uncertainty from the config"), so the
/// refit cannot absorb a small effect into them.
fn known_nominal() -> ehactl_plant::PlantParams {
    let mut p = testrig().plant;
    for k in [
        "valve.rated_flow",
        "fluid.bulk_modulus",
        "mechanics.mass",
        "mechanics.damping",
        "mechanics.load_stiffness",
    ] {
        p.uncertainty.insert(
            k.into(),
            ehactl_plant::params::Uncertainty::Relative("0%".into()),
        );
    }
    p
}

/// Why the known misses above are misses: with the nominal stated as known, the same small
/// records are not `none` (the refit within the default ±15 % had absorbed the effect), while
/// the clean records stay `none`. And no confident wrong name: a cause other than the hidden
/// effect (a look-alike at so small a size) comes with an ambiguity naming it.
fn check_small_known(e: EffectId) {
    let seed = 3100 + EffectId::ALL.iter().position(|x| *x == e).unwrap() as u64;
    let (rec, alpha) = with_small(seed, e);
    let d = diagnose(&known_nominal(), &rec, None, &Options::default()).unwrap();
    let report = format!(
        "{} (α = {alpha:.3}), nominal known: cause {}, ambiguities {:?}\n{}",
        e.as_str(),
        d.cause,
        d.ambiguities,
        d.summary
    );
    assert_ne!(d.cause, "none", "{report}");
    let named = format!("`{}`", d.cause);
    assert!(
        d.cause == e.as_str()
            || d.cause == "unexplained"
            || d.ambiguities.iter().any(|a| a.contains(&named)),
        "{report}"
    );
}

#[test]
fn own_clean_record_with_the_nominal_known_is_none() {
    for seed in [3000, 3001] {
        let d = diagnose(&known_nominal(), &clean(seed), None, &Options::default()).unwrap();
        assert_eq!(d.cause, "none", "seed {seed}: {}", d.summary);
    }
}

// Not `none` with the nominal known (2026-12-03); named: dead band and β(p); friction and the
// line `unexplained`; the saturation is answered `supply_pressure_drop`, the spool lag
// `time_delay`, each with an ambiguity (a weak winner: its fit at a corner of its range).
small!(
    small_friction_known_nominal_is_not_none,
    EffectId::Friction,
    check_small_known
);
small!(
    small_valve_deadband_known_nominal_is_not_none,
    EffectId::ValveDeadband,
    check_small_known
);
small!(
    small_valve_saturation_known_nominal_is_not_none,
    EffectId::ValveSaturation,
    check_small_known
);
small!(
    small_valve_dynamics_known_nominal_is_not_none,
    EffectId::ValveDynamics,
    check_small_known
);
small!(
    small_bulk_modulus_pressure_known_nominal_is_not_none,
    EffectId::BulkModulusPressure,
    check_small_known
);
// The position residual is coloured (2.0× its floor, Ljung–Box Q ≈ 5900) with nothing fitted:
// `none` while the soft level excused colour after no fit too; `unexplained` since
// `residual::LEVEL_SOFT_UNFITTED` (2026-12-03).
small!(
    small_line_dynamics_known_nominal_is_not_none,
    EffectId::LineDynamics,
    check_small_known
);
