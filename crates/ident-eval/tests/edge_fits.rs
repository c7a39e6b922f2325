//! A fit at the edge of its range is the closest catalogue effect, not the cause
//! (`ehactl_ident::edge`, DIAGNOSIS.md step 7 "An edge fit is not a cause"), and the detection
//! limits of the effects not named (`ehactl_ident::limits`, DIAGNOSIS.md "Detection limits").
//! Records of the test bench (`ehactl_ident_eval::synth`) with the effect set by hand.

use ehactl_ident::report::headline;
use ehactl_ident::{diagnose, Diagnosis, Options};
use ehactl_ident_eval::synth::{make_case, make_case_at, simulate};
use ehactl_plant::params::{SaturationVariant, TimeDelay};
use ehactl_plant::EffectId;

fn report(d: &Diagnosis) -> String {
    format!(
        "cause {} status {} causes {:?} closest {:?}\n{}\n{}",
        d.cause,
        d.status,
        d.causes,
        d.closest,
        headline(d),
        d.summary
    )
}

/// A spool limit of 2 % of the travel on the negative side (0.7 on the positive), below the
/// catalogue's lower bound of 5 %: the best catalogue fit sits on a bound of its range and
/// leaves the record unexplained, and the headline says so instead of naming it.
#[test]
fn a_limit_beyond_the_catalogue_range_is_an_edge_fit() {
    let mut case = make_case(1002, &[EffectId::ValveSaturation], 2.0);
    let s = case
        .truth
        .effects
        .valve_saturation
        .as_mut()
        .expect("hidden");
    s.variant = SaturationVariant::Asymmetric;
    s.spool_limit = 0.7;
    s.spool_limit_negative = 0.02;
    let rec = simulate(&case.truth, &case.record.u, 1e-3, "asymmetric limit");
    let d = diagnose(&case.nominal.plant, &rec, None, &Options::default()).unwrap();
    let r = report(&d);
    assert_eq!(d.status, "edge_fit", "{r}");
    assert_eq!(d.cause, "unexplained", "{r}");
    let c = d.closest.as_ref().expect("closest effect");
    assert!(
        c.at_edge && c.reasons.iter().any(|x| x.contains("bound")),
        "{r}"
    );
    let h = headline(&d);
    assert!(
        h.starts_with("Closest catalogue effect: ") && h.contains("not explained"),
        "{r}"
    );
    assert!(d.summary.starts_with("The record is not explained"), "{r}");
}

/// A line record sampled at 250 Hz (Nyquist 125 Hz) with only the mount to test: its best fit
/// puts the mount's mode √(k/m)/2π far above Nyquist, where the record cannot show a mode. It
/// is the closest effect, not the cause.
#[test]
fn a_mount_above_nyquist_is_not_the_cause_of_a_line() {
    let case = make_case_at(1007, &[EffectId::LineDynamics], 2.0, 4e-3);
    let opts = Options {
        effects: vec![EffectId::FlexibleMount],
        ..Options::default()
    };
    let d = diagnose(&case.nominal.plant, &case.record, None, &opts).unwrap();
    let r = report(&d);
    assert_eq!(d.cause, "unexplained", "{r}");
    assert_eq!(d.status, "edge_fit", "{r}");
    let c = d.closest.as_ref().expect("closest effect");
    assert_eq!(c.effect, "flexible_mount", "{r}");
    assert!(c.reasons.iter().any(|x| x.contains("Nyquist")), "{r}");
    // The mode itself, from the fitted parameters: above 125 Hz.
    let p = &d.extended_params;
    let f = (p["effects.flexible_mount.stiffness"] / p["effects.flexible_mount.load_mass"]).sqrt()
        / std::f64::consts::TAU;
    assert!(f > 125.0, "{f} Hz\n{r}");
}

/// The test bench's clean record with a delay of 0.02 ms, a fiftieth of its 1 ms sample, and
/// the delay the only candidate: its fit (0.015 ms) sits on the lower bound of its range
/// [0, 60 ms] and passed the acceptance test on a gain within the noise floor (-1 % held-out
/// NRMSE at the floor). It is not accepted: the answer is `none`, and the `none` states the
/// delay's detection limit, above 0.02 ms.
#[test]
fn a_tiny_delay_is_not_a_cause() {
    let mut case = make_case(2000, &[], 2.0);
    case.truth.effects.time_delay = Some(TimeDelay {
        enabled: true,
        delay: 2e-5,
    });
    let rec = simulate(&case.truth, &case.record.u, 1e-3, "tiny delay");
    let opts = Options {
        effects: vec![EffectId::TimeDelay],
        ..Options::default()
    };
    let d = diagnose(&case.nominal.plant, &rec, None, &opts).unwrap();
    let r = report(&d);
    assert_eq!(d.cause, "none", "{r}");
    assert_eq!(d.status, "none", "{r}");
    assert!(d.causes.is_empty(), "{r}");
    let c = &d.candidates[0];
    assert!(
        c.evidence
            .contains("not accepted: its fit is at the edge of its range"),
        "{r}\n{}",
        c.evidence
    );
    let l = &d.detection_limits["time_delay"];
    assert_eq!(l.unit, "s");
    assert!(l.limit.is_some_and(|v| v > 2e-5), "{l:?}");
    assert!(
        headline(&d).contains("no effect above these detection limits"),
        "{r}"
    );
}

/// The limit the record states is what the diagnosis finds: on the clean test-bench record,
/// a delay of 3× the stated limit hidden in the same record (same command and noise) is
/// named, one of a third of it is not. (That one is answered `internal_leakage` of
/// 2e-15 m³/(s·Pa), accepted on the floor-weighted J 1.37 → 1.05: a small leftover on the
/// position channel, not an edge fit, which this rule leaves alone.)
#[test]
fn the_stated_delay_limit_is_what_the_diagnosis_finds() {
    let case = make_case(2000, &[], 2.0);
    let opts = Options::default();
    let d = diagnose(&case.nominal.plant, &case.record, None, &opts).unwrap();
    assert_eq!(d.cause, "none", "{}", report(&d));
    assert_eq!(
        d.detection_limits.len(),
        EffectId::ALL.len(),
        "{}",
        report(&d)
    );
    let limit = d.detection_limits["time_delay"].limit.expect("a limit");
    let with = |delay: f64| {
        let mut t = case.truth.clone();
        t.effects.time_delay = Some(TimeDelay {
            enabled: true,
            delay,
        });
        let rec = simulate(&t, &case.record.u, 1e-3, "delay");
        diagnose(&case.nominal.plant, &rec, None, &opts).unwrap()
    };
    let above = with(3.0 * limit);
    assert_eq!(
        above.cause,
        "time_delay",
        "limit {limit}: {}",
        report(&above)
    );
    let below = with(limit / 3.0);
    assert!(
        !below.causes.iter().any(|c| c == "time_delay"),
        "limit {limit}: {}",
        report(&below)
    );
}
