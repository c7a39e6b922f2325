//! Seeded generator of measured-like records with hidden effects (for the acceptance tests,
//! the 100-case evaluation and the benchmark): the plant of `configs/diagnose_testrig.toml`
//! with one or more catalogue effects switched on at realistic parameters, driven by a rich
//! open-loop valve command, sampled with the rig's sensor noise; the nominal config handed
//! to the diagnosis lacks the effects and has ±10 % errors in valve gain, β₀, damping, mass
//! and spring rate.

use ehactl_config::RigConfig;
use ehactl_ident::data::{Channel, ChannelKind, Record};
use ehactl_plant::{EffectId, Plant, PlantParams};

/// The diagnosis test bench config (embedded copy of `configs/diagnose_testrig.toml`).
pub const TESTRIG_TOML: &str = include_str!("../../../configs/diagnose_testrig.toml");

/// The test bench as a rig config.
pub fn testrig() -> RigConfig {
    RigConfig::from_toml_str(TESTRIG_TOML).expect("configs/diagnose_testrig.toml is valid")
}

pub use crate::rng::Rng;

/// Valve command (V): random steps (levels in ±9 V, a third of them small, holds of
/// 60–180 ms, so velocity reverses often and the command dwells near zero and near its limits)
/// plus a repeating 1–40 Hz sine sweep of 1.5 V, stationary so every part of the record has
/// the same content.
pub fn excitation(seed: u64, dt: f64, n: usize) -> Vec<f64> {
    let mut rng = Rng::new(seed.wrapping_mul(31).wrapping_add(7));
    let mut u = Vec::with_capacity(n);
    let mut level = 0.0;
    let mut next_change = 0.05;
    let period = 0.5;
    for k in 0..n {
        let t = k as f64 * dt;
        if t >= next_change {
            level = if rng.uniform() < 0.33 {
                rng.range(-1.0, 1.0)
            } else {
                rng.range(-9.0, 9.0)
            };
            next_change = t + rng.range(0.06, 0.18);
        }
        let tau = t % period;
        let (f0, f1) = (1.0, 40.0);
        let phase = std::f64::consts::TAU * (f0 * tau + 0.5 * (f1 - f0) / period * tau * tau);
        u.push(if t < 0.05 {
            0.0
        } else {
            level + 1.5 * phase.sin()
        });
    }
    u
}

/// Switch effect `e` on in `p` with parameters drawn from a realistic range for the test bench.
/// (One function per effect in [`crate::hide`].)
pub fn hide(e: EffectId, p: &mut PlantParams, rng: &mut Rng) {
    crate::hide::hide(e, p, rng)
}

/// Structural variants the evaluation hides besides each effect's default one
/// ([`make_case_variant`]; DIAGNOSIS.md "Effect variants").
pub const VARIANT_CASES: [(EffectId, &str); 2] = [
    (EffectId::Friction, "lugre"),
    (EffectId::LineDynamics, "hose"),
];

/// Switch effect `e` on in `p` in its structural variant `variant` (one of [`VARIANT_CASES`],
/// else its default as [`hide`]) with parameters drawn from a realistic range.
pub fn hide_variant(e: EffectId, variant: &str, p: &mut PlantParams, rng: &mut Rng) {
    crate::hide::hide_variant(e, variant, p, rng)
}

/// One generated case.
#[derive(Debug, Clone)]
pub struct Case {
    /// Seed.
    pub seed: u64,
    /// Effects hidden in the data.
    pub hidden: Vec<EffectId>,
    /// Config the diagnosis gets (no hidden effect, ±10 % errors).
    pub nominal: RigConfig,
    /// Plant that made the data.
    pub truth: PlantParams,
    /// The measured-like record.
    pub record: Record,
}

/// Generate a case: `duration` s at the test bench's 1 kHz.
pub fn make_case(seed: u64, hidden: &[EffectId], duration: f64) -> Case {
    make_case_at(seed, hidden, duration, 1e-3)
}

/// Generate a case at sample period `dt` (s).
pub fn make_case_at(seed: u64, hidden: &[EffectId], duration: f64, dt: f64) -> Case {
    let hidden: Vec<(EffectId, &str)> = hidden.iter().map(|&e| (e, "")).collect();
    make_case_variants(seed, &hidden, duration, dt)
}

/// Generate a case at 1 kHz with effect `e` hidden in structural variant `variant`
/// ([`hide_variant`]).
pub fn make_case_variant(seed: u64, e: EffectId, variant: &str, duration: f64) -> Case {
    make_case_variants(seed, &[(e, variant)], duration, 1e-3)
}

fn make_case_variants(seed: u64, hidden: &[(EffectId, &str)], duration: f64, dt: f64) -> Case {
    let mut rng = Rng::new(seed);
    let rig = testrig();
    let mut truth = rig.plant.clone();
    truth.sensors.seed = seed;
    for &(e, variant) in hidden {
        hide_variant(e, variant, &mut truth, &mut rng);
    }
    let hidden: Vec<EffectId> = hidden.iter().map(|h| h.0).collect();
    let hidden = &hidden[..];
    let mut nominal = rig.clone();
    nominal.run.control_rate_hz = 1.0 / dt;
    {
        let p = &mut nominal.plant;
        let mut err = || rng.range(0.9, 1.1);
        p.valve.rated_flow = p.valve.rated_flow.map(|q| q * err());
        p.fluid.bulk_modulus *= err();
        p.mechanics.damping *= err();
        p.mechanics.mass *= err();
        p.mechanics.load_stiffness *= err();
    }
    let n = (duration / dt).round() as usize;
    let u = excitation(seed, dt, n);
    let record = simulate(&truth, &u, dt, &format!("synthetic seed {seed}"));
    Case {
        seed,
        hidden: hidden.to_vec(),
        nominal,
        truth,
        record,
    }
}

/// The record the plant `truth` gives for the valve command `u` (V) sampled at `dt` (s):
/// force, position and both chamber pressures as its sensors measure them (with their noise).
pub fn simulate(truth: &PlantParams, u: &[f64], dt: f64, source: &str) -> Record {
    let n = u.len();
    let mut plant = Plant::configure(truth, dt).expect("generated plant is valid");
    let kinds = [
        ChannelKind::Force,
        ChannelKind::Position,
        ChannelKind::PressureA,
        ChannelKind::PressureB,
    ];
    let mut cols: Vec<Vec<f64>> = vec![Vec::with_capacity(n); kinds.len()];
    let mut t = Vec::with_capacity(n);
    for &uk in u {
        let m = plant.measure();
        t.push(m.t);
        for (c, k) in kinds.iter().enumerate() {
            cols[c].push(k.pick(&m));
        }
        plant.step(uk).expect("generated plant stays finite");
    }
    let channels = kinds
        .iter()
        .zip(cols)
        .map(|(k, v)| Channel {
            kind: *k,
            values: v,
        })
        .collect();
    Record::from_columns(source, t, u.to_vec(), channels, None, 0)
        .expect("generated record is valid")
}

/// Sensor zero errors of a realistic bench, per channel (SI): pressure transducers +2.0 and
/// −1.5 bar (≈ 0.8 % and 0.6 % of a 250 bar range), the load cell 5 % of the signal's
/// standard deviation, the position transducer +0.5 mm (its zero against the mounting).
pub fn realistic_offsets(rec: &Record) -> Vec<(ChannelKind, f64)> {
    rec.channels
        .iter()
        .filter_map(|c| match c.kind {
            ChannelKind::PressureA => Some((c.kind, 2.0e5)),
            ChannelKind::PressureB => Some((c.kind, -1.5e5)),
            ChannelKind::Force => Some((c.kind, 0.05 * ehactl_ident::replay::std(&c.values))),
            ChannelKind::Position => Some((c.kind, 5.0e-4)),
            _ => None,
        })
        .collect()
}

/// Add constant sensor offsets (per channel kind, SI) to a record's measured channels.
pub fn add_sensor_offsets(rec: &mut Record, offsets: &[(ChannelKind, f64)]) {
    for c in rec.channels.iter_mut() {
        for (_, b) in offsets.iter().filter(|(k, _)| *k == c.kind) {
            c.values.iter_mut().for_each(|v| *v += b);
        }
    }
}

/// Write a record as CSV in the format of docs/design.md ("Measured-data format").
pub fn to_csv(rec: &Record) -> String {
    let mut s = String::from("t,u");
    for c in &rec.channels {
        s.push(',');
        s.push_str(c.kind.column());
    }
    s.push('\n');
    for k in 0..rec.len() {
        s.push_str(&format!("{:e},{:e}", rec.t[k], rec.u[k]));
        for c in &rec.channels {
            s.push_str(&format!(",{:e}", c.values[k]));
        }
        s.push('\n');
    }
    s
}

/// The record `clean` with a hidden effect added at a small magnitude: `clean` +
/// α·(`full` − `clean`), where `full` is the same excitation and sensor noise with the effect
/// switched on, and α puts the residual of the largest channel at `level` × its sensor noise
/// σ (`noise` per channel kind, SI), i.e. √(1 + (α·rms(full − clean)/σ)²) = `level`. The noise
/// cancels in the difference, so to first order this is the effect at a smaller parameter with
/// its signature (band, dependence on the state, lag) kept exactly. Returns the record and α;
/// `None` when the effect changes no channel or `level` ≤ 1.
pub fn small_effect(
    clean: &Record,
    full: &Record,
    level: f64,
    noise: impl Fn(ChannelKind) -> f64,
) -> Option<(Record, f64)> {
    let rms = |a: &[f64], b: &[f64]| {
        (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len().max(1) as f64).sqrt()
    };
    let worst = clean
        .channels
        .iter()
        .zip(&full.channels)
        .map(|(c, f)| rms(&f.values, &c.values) / noise(c.kind).max(1e-300))
        .fold(0.0, f64::max);
    if worst <= 0.0 || level <= 1.0 {
        return None;
    }
    let alpha = (level * level - 1.0).sqrt() / worst;
    let mut rec = clean.clone();
    for (c, f) in rec.channels.iter_mut().zip(&full.channels) {
        for (y, yf) in c.values.iter_mut().zip(&f.values) {
            *y += alpha * (yf - *y);
        }
    }
    // A closed-loop record's command moves with the effect too (first order, as the outputs).
    for (u, uf) in rec.u.iter_mut().zip(&full.u) {
        *u += alpha * (uf - *u);
    }
    Some((rec, alpha))
}

/// The small case of [`make_case_small`] made physical: the hidden effect at the blend's α
/// ([`crate::hide::at_strength`]), the same excitation, noise draws and nominal errors.
/// `truth` keeps the full-size effect and α is returned, so that the blend's scoring
/// (`crate::limscore::small_size`) gives the physical size.
pub fn make_case_small_physical(seed: u64, e: EffectId, level: f64, duration: f64) -> (Case, f64) {
    let (mut case, alpha) = make_case_small(seed, e, level, duration);
    if alpha > 0.0 {
        let mut truth = case.truth.clone();
        crate::hide::at_strength(e, &mut truth, alpha);
        let source = format!(
            "synthetic seed {seed}, {} physically at α = {alpha:.3e}",
            e.as_str()
        );
        case.record = simulate(&truth, &case.record.u, 1e-3, &source);
    }
    (case, alpha)
}

/// Sensor noise σ of the test bench's channel `kind` (SI), from `configs/diagnose_testrig.toml`.
pub fn testrig_noise(kind: ChannelKind) -> f64 {
    let s = &testrig().plant.sensors;
    match kind {
        ChannelKind::Force => s.force.noise,
        ChannelKind::Position => s.position.noise,
        ChannelKind::PressureA | ChannelKind::PressureB => s.pressure.noise,
        ChannelKind::Spool => s.spool.noise,
    }
}

/// A case of [`make_case`] with the single effect `e` at a small magnitude: its residual at
/// `level` × the sensor noise on the channel it moves most ([`small_effect`]). The nominal
/// config has the same ±10 % errors as [`make_case`]'s; `truth` is the plant with the effect
/// at its drawn (full) parameters, of which the record carries the fraction α (returned).
pub fn make_case_small(seed: u64, e: EffectId, level: f64, duration: f64) -> (Case, f64) {
    let mut case = make_case(seed, &[e], duration);
    let mut clean_truth = testrig().plant;
    clean_truth.sensors.seed = seed;
    let clean = simulate(&clean_truth, &case.record.u, 1e-3, "clean");
    let (mut rec, alpha) =
        small_effect(&clean, &case.record, level, testrig_noise).unwrap_or((clean, 0.0));
    rec.source = format!(
        "synthetic seed {seed}, {} at {level}× the noise",
        e.as_str()
    );
    case.record = rec;
    (case, alpha)
}
