//! The next test: for every effect whose detection limit is loose and for every ambiguity, the
//! excitation that would tighten the limit or separate the pair, as a `[setpoint]` section
//! that `ehactl run` plays (DIAGNOSIS.md "The next test").
//!
//! `ehactl run` plays the config's `[setpoint]` generator (`ehactl_control::setpoint`: step,
//! ramp, sine, chirp, static + dynamic, random steps); it takes no recorded reference file. So
//! each proposal is a `[setpoint]` section, written into the diagnosis' `--out` directory as
//! `next_test_N.toml`, scaled to the record's own setpoint (the valve command `u` in V for an
//! open-loop record, the recorded `ref` in the loop's unit otherwise) and kept inside its
//! range. Four kinds of excitation, chosen per effect by what shows it (Merritt 1967,
//! "Hydraulic Control Systems", ch. 5 and 8, for the valve and load signatures):
//! - slow reversals (a sine of 0.5 Hz at 15 % of the record's setpoint): Coulomb friction
//!   jumps at each velocity reversal, a dead band is a command gap around zero;
//! - large levels (random steps over the record's whole range, held 0.2 s): a spool limit caps
//!   the flow at large commands, a supply drop sags with the flow drawn, and the small levels
//!   among them cross the dead band;
//! - holds (random steps over 30 % of the range, held 1 s): leakage shows in the pressures
//!   that settle, not in the fast response;
//! - a wide band (a log chirp from 1 Hz to 40 % of the sample rate at 30 % of the range):
//!   a spool lag, a delay, line and mount modes, β(p) and a sensor tone are dynamic and show
//!   above the record's band.

use crate::data::Record;
use crate::limits::DetectionLimit;
use ehactl_control::setpoint::{SetpointConfig, SetpointKind, Sweep};
use ehactl_plant::EffectId;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A limit whose position on the log scale of the catalogue range is at least this is loose
/// (-): past the geometric middle of what the catalogue holds, or not detectable at all.
pub const LOOSE: f64 = 0.5;

/// At most this many proposals (the ambiguities first), so that the files stay few.
pub const MAX_TESTS: usize = 6;

/// Duration of each proposed run (s).
pub const DURATION: f64 = 4.0;

/// What kind of excitation shows an effect (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Excitation {
    /// Slow reversals at a small amplitude.
    SlowReversals,
    /// Large levels over the whole range.
    LargeLevels,
    /// Long holds.
    Holds,
    /// A wide frequency band.
    WideBand,
}

impl Excitation {
    fn of(e: EffectId) -> Self {
        use EffectId::*;
        match e {
            Friction | ValveDeadband => Self::SlowReversals,
            ValveSaturation | SupplyPressureDrop => Self::LargeLevels,
            InternalLeakage | ExternalLeakage => Self::Holds,
            ValveDynamics | TimeDelay | LineDynamics | FlexibleMount | BulkModulusPressure
            | SensorTone => Self::WideBand,
        }
    }

    /// What separates `a` from `b`: a wide band when either is dynamic (the modes and lags
    /// differ in frequency), large levels for a valve-side pair of static effects (a dead band
    /// against a limit or a supply drop: small and large commands in one run), else `a`'s.
    fn of_pair(a: EffectId, b: EffectId) -> Self {
        let (x, y) = (Self::of(a), Self::of(b));
        if x == Self::WideBand || y == Self::WideBand {
            Self::WideBand
        } else if x != y && (x == Self::LargeLevels || y == Self::LargeLevels) {
            Self::LargeLevels
        } else {
            x
        }
    }

    fn words(self) -> &'static str {
        match self {
            Self::SlowReversals => "slow reversals at a small amplitude (a 0.5 Hz sine at 15 % of the record's setpoint range): friction jumps at each velocity reversal, a dead band is a command gap around zero",
            Self::LargeLevels => "large levels over the record's whole setpoint range (random steps held 0.2 s): a spool limit caps the flow at large commands, a supply drop sags with the flow drawn, the small levels among them cross a dead band",
            Self::Holds => "long holds (random steps over 30 % of the range, held 1 s; on a rig, against an end stop): leakage shows in the pressures that settle",
            Self::WideBand => "a wide band (a log chirp from 1 Hz to 40 % of the sample rate at 30 % of the setpoint range): lags, delays and modes differ above the record's band",
        }
    }
}

/// One proposed test.
#[derive(Debug, Clone, Serialize)]
pub struct NextTest {
    /// `tighten` (a loose detection limit) or `separate` (an ambiguity).
    pub purpose: String,
    /// The effect ids it is for.
    pub effects: Vec<String>,
    /// The excitation kind.
    pub excitation: Excitation,
    /// The excitation and why it shows the effects, in words.
    pub why: String,
    /// File in the `--out` directory holding the `[setpoint]` section.
    pub file: String,
    /// The setpoint section (the record's setpoint unit: V of valve command open loop, the
    /// loop's unit closed loop).
    pub setpoint: SetpointConfig,
    /// Run length (s): `ehactl run … --duration`.
    pub duration: f64,
}

/// The record's setpoint (the recorded `ref`, else the command `u`): its centre and its
/// half range (2nd to 98th percentile), in its unit.
fn setpoint_scale(rec: &Record) -> (f64, f64) {
    let s = rec.reference.as_deref().unwrap_or(&rec.u);
    let mut v: Vec<f64> = s.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (0.0, 1.0);
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let (lo, hi) = (q(0.02), q(0.98));
    let half = (0.5 * (hi - lo)).max(1e-12);
    // An open-loop command is centred on zero flow; a loop's setpoint on its own centre.
    let centre = if rec.reference.is_some() {
        0.5 * (hi + lo)
    } else {
        0.0
    };
    (centre, half)
}

/// The `[setpoint]` section of excitation `x` for a record of sample period `dt` (s) whose
/// setpoint has centre `c` and half range `a` ([`setpoint_scale`]).
fn section(x: Excitation, c: f64, a: f64, dt: f64, seed: u64) -> SetpointConfig {
    let mut s = SetpointConfig {
        kind: SetpointKind::Sine,
        initial: 0.0,
        final_value: 0.0,
        start: 0.05,
        // The sweep's length; the other kinds have none (the run's `--duration` ends them).
        duration: 0.0,
        offset: c,
        amplitude: 0.0,
        f0: 0.0,
        f1: 0.0,
        sweep: Sweep::Linear,
        steps: 0,
        ramp_time: 0.0,
        hold: 0.0,
        seed: 0,
    };
    match x {
        Excitation::SlowReversals => {
            s.amplitude = 0.15 * a;
            s.f0 = 0.5;
        }
        Excitation::LargeLevels | Excitation::Holds => {
            let (share, hold) = if x == Excitation::Holds {
                (0.3, 1.0)
            } else {
                (1.0, 0.2)
            };
            s.kind = SetpointKind::RandomSteps;
            s.initial = c - share * a;
            s.final_value = c + share * a;
            s.hold = hold;
            s.seed = seed;
        }
        Excitation::WideBand => {
            s.kind = SetpointKind::Chirp;
            s.duration = DURATION;
            s.amplitude = 0.3 * a;
            s.f0 = 1.0;
            s.f1 = (0.4 / dt).max(2.0);
            s.sweep = Sweep::Log;
        }
    }
    s
}

/// The effect ids named in backquotes in an ambiguity sentence, in order, without repeats.
fn effects_in(text: &str) -> Vec<EffectId> {
    let mut out: Vec<EffectId> = Vec::new();
    for part in text.split('`').skip(1).step_by(2) {
        if let Some(e) = EffectId::parse(part) {
            if !out.contains(&e) {
                out.push(e);
            }
        }
    }
    out
}

/// The proposed tests of a diagnosis of record `rec` with `ambiguities` and detection
/// `limits` (`Diagnosis::ambiguities`, `Diagnosis::detection_limits`): one per ambiguity (its
/// first two effects), then one per loose detection limit ([`LOOSE`]) whose excitation is not
/// already proposed, at most [`MAX_TESTS`].
pub fn next_tests(
    ambiguities: &[String],
    limits: &BTreeMap<String, DetectionLimit>,
    rec: &Record,
) -> Vec<NextTest> {
    let dt = sample_period(rec);
    let (c, a) = setpoint_scale(rec);
    let mut wanted: Vec<(&str, Vec<EffectId>, Excitation)> = Vec::new();
    for amb in ambiguities {
        if let [x, y, ..] = effects_in(amb)[..] {
            if !wanted.iter().any(|w| w.1 == [x, y] || w.1 == [y, x]) {
                wanted.push(("separate", vec![x, y], Excitation::of_pair(x, y)));
            }
        }
    }
    let mut loose: Vec<(&String, &DetectionLimit)> = limits
        .iter()
        .filter(|(_, l)| {
            l.looseness >= LOOSE && (l.limit.is_some() || l.note.starts_with("not detectable"))
        })
        .collect();
    loose.sort_by(|x, y| y.1.looseness.total_cmp(&x.1.looseness));
    for (name, _) in loose {
        let Some(e) = EffectId::parse(name) else {
            continue;
        };
        let x = Excitation::of(e);
        match wanted.iter_mut().find(|w| w.0 == "tighten" && w.2 == x) {
            Some(w) => w.1.push(e),
            None => wanted.push(("tighten", vec![e], x)),
        }
    }
    wanted
        .into_iter()
        .take(MAX_TESTS)
        .enumerate()
        .map(|(i, (purpose, effects, x))| make(purpose, &effects, x, (c, a, dt), i))
        .collect()
}

/// The test number `i` (0-based) for `effects` with excitation `x` on a record of setpoint
/// centre, half range and sample period `scale`.
fn make(
    purpose: &str,
    effects: &[EffectId],
    x: Excitation,
    scale: (f64, f64, f64),
    i: usize,
) -> NextTest {
    let (c, a, dt) = scale;
    NextTest {
        purpose: purpose.to_string(),
        effects: effects.iter().map(|e| e.as_str().to_string()).collect(),
        excitation: x,
        why: x.words().to_string(),
        file: format!("next_test_{}.toml", i + 1),
        setpoint: section(x, c, a, dt, 1000 + i as u64),
        duration: DURATION,
    }
}

/// The test that separates `a` from `b` on record `rec` (what [`next_tests`] proposes for an
/// ambiguity naming them).
pub fn separating(a: EffectId, b: EffectId, rec: &Record) -> NextTest {
    let (c, h) = setpoint_scale(rec);
    make(
        "separate",
        &[a, b],
        Excitation::of_pair(a, b),
        (c, h, sample_period(rec)),
        0,
    )
}

/// The test that would tighten the detection limit of `e` on record `rec` (what
/// [`next_tests`] proposes for a loose limit of `e` alone).
pub fn tightening(e: EffectId, rec: &Record) -> NextTest {
    let (c, h) = setpoint_scale(rec);
    let x = Excitation::of(e);
    make("tighten", &[e], x, (c, h, sample_period(rec)), 0)
}

/// The record's mean sample period (s); 1 ms for a record of one sample.
fn sample_period(rec: &Record) -> f64 {
    if rec.t.len() > 1 {
        (rec.t[rec.t.len() - 1] - rec.t[0]) / (rec.t.len() - 1) as f64
    } else {
        1e-3
    }
}

/// The setpoint samples of test `t` at period `dt` (s) over its duration: what `ehactl run`
/// plays (`ehactl_control::setpoint::Setpoint`).
pub fn samples(t: &NextTest, dt: f64) -> Vec<f64> {
    let sp = ehactl_control::setpoint::Setpoint::new(&t.setpoint);
    let n = (t.duration / dt).round() as usize;
    (0..n).map(|k| sp.sample(k as f64 * dt).0).collect()
}

/// The `[setpoint]` section of `t` as TOML, headed by comments that say what it is for and
/// how to run it.
pub fn toml_text(t: &NextTest) -> String {
    let s = &t.setpoint;
    let kind = serde_json::to_value(s.kind)
        .ok()
        .and_then(|v| v.as_str().map(String::from))
        .unwrap_or_default();
    let mut r = String::new();
    let _ = writeln!(
        r,
        "# Next test ({} {}): {}.\n# Put this [setpoint] section in place of the config's own and run\n#   ehactl run CONFIG --duration {} --out {}\n# then diagnose both records: ehactl diagnose --config CONFIG --data {} --validate RECORD\n# (units: the record's setpoint, V of valve command open loop, the loop's unit closed loop)\n[setpoint]\nkind = \"{kind}\"",
        t.purpose,
        t.effects.join(" / "),
        t.why,
        t.duration,
        t.file.replace(".toml", ".mcap"),
        t.file.replace(".toml", ".mcap"),
    );
    let mut kv = |k: &str, v: f64| {
        let _ = writeln!(r, "{k} = {v:?}");
    };
    kv("start", s.start);
    match s.kind {
        SetpointKind::RandomSteps => {
            kv("initial", s.initial);
            kv("final", s.final_value);
            kv("hold", s.hold);
            let _ = writeln!(r, "seed = {}", s.seed);
        }
        _ => {
            kv("offset", s.offset);
            kv("amplitude", s.amplitude);
            kv("f0", s.f0);
            if s.kind == SetpointKind::Chirp {
                kv("f1", s.f1);
                kv("duration", s.duration);
                let _ = writeln!(r, "sweep = \"log\"");
            }
        }
    }
    r
}

/// The report.md section: one line per proposed test of `tests`.
pub fn write_section(r: &mut String, tests: &[NextTest]) {
    if tests.is_empty() {
        return;
    }
    let _ = writeln!(r, "\n## The next test\n\nEach file holds a `[setpoint]` section for `ehactl run` (DIAGNOSIS.md \"The next test\"); diagnose the new record and this one together (`--data` the new one `--validate` this one: fitted where the excitation tells the effects apart, checked on this record).\n\n| file | for | effects | excitation |\n|---|---|---|---|");
    for t in tests {
        let _ = writeln!(
            r,
            "| [`{}`]({}) | {} | {} | {} |",
            t.file,
            t.file,
            t.purpose,
            t.effects
                .iter()
                .map(|e| format!("`{e}`"))
                .collect::<Vec<_>>()
                .join(", "),
            t.why
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ambiguities_name_their_effects() {
        let a = "`valve_deadband` vs `supply_pressure_drop`: … (`valve_deadband` again)";
        assert_eq!(
            effects_in(a),
            vec![EffectId::ValveDeadband, EffectId::SupplyPressureDrop]
        );
        assert!(effects_in("no `effect` here").is_empty());
    }

    /// The pair rules of the module doc.
    #[test]
    fn pairs_get_the_excitation_that_tells_them_apart() {
        use EffectId::*;
        let p = Excitation::of_pair;
        assert_eq!(p(LineDynamics, FlexibleMount), Excitation::WideBand);
        assert_eq!(
            p(ValveDeadband, SupplyPressureDrop),
            Excitation::LargeLevels
        );
        assert_eq!(
            p(ValveSaturation, SupplyPressureDrop),
            Excitation::LargeLevels
        );
        assert_eq!(p(Friction, ValveDeadband), Excitation::SlowReversals);
        assert_eq!(p(InternalLeakage, ExternalLeakage), Excitation::Holds);
    }

    /// The sections stay inside the record's range and below its Nyquist frequency.
    #[test]
    fn sections_stay_inside_the_record() {
        for x in [
            Excitation::SlowReversals,
            Excitation::LargeLevels,
            Excitation::Holds,
            Excitation::WideBand,
        ] {
            let s = section(x, 0.0, 8.0, 1e-3, 1);
            let sp = ehactl_control::setpoint::Setpoint::new(&s);
            let ((lo, _), (hi, _)) = sp.envelope();
            assert!(lo >= -8.0 - 1e-9 && hi <= 8.0 + 1e-9, "{x:?}: {lo} {hi}");
            assert!(s.f1 < 500.0 && s.f0 < 500.0, "{x:?}");
        }
    }
}
