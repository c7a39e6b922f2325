//! Seeded generator of measured-like records with hidden effects (for the acceptance tests,
//! the 100-case evaluation and the benchmark): the plant of `configs/diagnose_testrig.toml`
//! with one or more catalogue effects switched on at realistic parameters, driven by a rich
//! open-loop valve command, sampled with the rig's sensor noise; the nominal config handed
//! to the diagnosis lacks the effects and has ±10 % errors in valve gain, β₀, damping, mass
//! and spring rate.

use crate::data::{Channel, ChannelKind, Record};
use ehactl_config::RigConfig;
use ehactl_plant::params::*;
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
pub fn hide(e: EffectId, p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    match e {
        EffectId::Friction => {
            let fc = rng.range(150.0, 400.0);
            ef.friction = Some(Friction {
                enabled: true,
                variant: Default::default(),
                coulomb_force: fc,
                static_force: fc * rng.range(1.1, 1.6),
                stribeck_velocity: rng.log_range(0.005, 0.02),
                viscous: 0.0,
                bristle_stiffness: 0.0,
                bristle_damping: 0.0,
            });
        }
        EffectId::ValveDeadband => {
            ef.valve_deadband = Some(ValveDeadband {
                enabled: true,
                variant: Default::default(),
                deadzone: 0.0,
                overlap: rng.range(0.05, 0.12),
                zero_offset: rng.range(-0.01, 0.01),
            });
        }
        EffectId::ValveSaturation => {
            ef.valve_saturation = Some(ValveSaturation {
                enabled: true,
                variant: Default::default(),
                spool_limit_negative: 1.0,
                spool_limit: rng.range(0.45, 0.7),
                max_flow: 0.0,
            });
        }
        EffectId::ValveDynamics => {
            ef.valve_dynamics = Some(ValveDynamics {
                enabled: true,
                order: 2,
                time_constant: 0.0,
                natural_frequency: std::f64::consts::TAU * rng.range(15.0, 45.0),
                damping_ratio: rng.range(0.5, 0.9),
            });
        }
        EffectId::InternalLeakage => {
            ef.internal_leakage = Some(Leakage {
                enabled: true,
                variant: Default::default(),
                coefficient_b: 0.0,
                coefficient: rng.log_range(2e-12, 8e-12),
            })
        }
        EffectId::ExternalLeakage => {
            ef.external_leakage = Some(Leakage {
                enabled: true,
                variant: Default::default(),
                coefficient_b: 0.0,
                coefficient: rng.log_range(2e-12, 8e-12),
            })
        }
        EffectId::BulkModulusPressure => {
            ef.bulk_modulus_pressure = Some(BulkModulusPressure {
                enabled: true,
                variant: Default::default(),
                air_fraction: 0.0,
                polytropic_index: 1.4,
                slope: rng.range(80.0, 200.0),
                max: 2.2e9,
            })
        }
        EffectId::LineDynamics => {
            ef.line_dynamics = Some(LineDynamics {
                enabled: true,
                length: rng.range(1.5, 4.0),
                diameter: rng.range(6e-3, 10e-3),
                segments: 3,
                bulk_modulus: None,
                port_volume: 0.0,
                variant: Default::default(),
                wall_compliance: 0.0,
                resistance: 0.0,
                friction: Default::default(),
            })
        }
        EffectId::FlexibleMount => {
            let m = rng.range(10.0, 40.0);
            let k = rng.log_range(2e6, 8e6);
            ef.flexible_mount = Some(FlexibleMount {
                enabled: true,
                variant: Default::default(),
                load_mass: m,
                stiffness: k,
                damping: rng.range(0.05, 0.2) * 2.0 * (k * m).sqrt(),
            });
        }
        EffectId::TimeDelay => {
            ef.time_delay = Some(TimeDelay {
                enabled: true,
                delay: rng.range(0.003, 0.010),
            })
        }
        EffectId::SensorTone => {
            let force = rng.uniform() < 0.5;
            let f = rng.range(80.0, 300.0);
            ef.sensor_tone = Some(if force {
                SensorTone {
                    enabled: true,
                    channel: SensorChannel::Force,
                    phases: vec![],
                    frequencies: vec![f],
                    amplitudes: vec![rng.range(20.0, 40.0)],
                }
            } else {
                SensorTone {
                    enabled: true,
                    channel: SensorChannel::PressureA,
                    phases: vec![],
                    frequencies: vec![f],
                    amplitudes: vec![rng.range(8e4, 1.6e5)],
                }
            });
        }
        EffectId::SupplyPressureDrop => {
            ef.supply_pressure_drop = Some(SupplyPressureDrop {
                enabled: true,
                variant: Default::default(),
                max_flow: 0.0,
                regulation_band: 0.0,
                volume: 0.0,
                resistance: rng.range(1.0e10, 2.5e10),
                time_constant: rng.log_range(0.01, 0.05),
            })
        }
    }
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
    let mass = p.mechanics.mass;
    match (e, variant) {
        // Seal friction with pre-sliding bristles (Canudas de Wit et al. 1995): pre-sliding
        // range F_C/σ₀ of 20–80 µm (tens of µm on hydraulic cylinder seals, e.g. Yanada &
        // Sekikawa 2008, Tribology International 41), bristle damping 10–50 % of critical.
        (EffectId::Friction, "lugre") => {
            let fc = rng.range(150.0, 400.0);
            let s0 = fc / rng.log_range(20e-6, 80e-6);
            p.effects.friction = Some(Friction {
                enabled: true,
                variant: FrictionVariant::Lugre,
                coulomb_force: fc,
                static_force: fc * rng.range(1.1, 1.6),
                stribeck_velocity: rng.log_range(0.005, 0.02),
                viscous: 0.0,
                bristle_stiffness: s0,
                bristle_damping: rng.range(0.1, 0.5) * 2.0 * (s0 * mass).sqrt(),
            });
        }
        // A 1.5–4 m hose of 8–13 mm bore, wall compliance 0.6–2.5·10⁻⁹ 1/Pa (β_eff ≈
        // 0.3–0.8 GPa), fittings 0.5–2·10⁹ Pa·s/m³; three segments (the fit uses two).
        (EffectId::LineDynamics, "hose") => {
            p.effects.line_dynamics = Some(LineDynamics {
                enabled: true,
                variant: LineVariant::Hose,
                length: rng.range(1.5, 4.0),
                diameter: rng.range(8e-3, 13e-3),
                segments: 3,
                bulk_modulus: None,
                port_volume: 0.0,
                friction: Default::default(),
                wall_compliance: rng.log_range(0.6e-9, 2.5e-9),
                resistance: rng.range(0.5e9, 2e9),
            });
        }
        _ => hide(e, p, rng),
    }
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
    let mut plant = Plant::configure(&truth, dt).expect("generated plant is valid");
    let kinds = [
        ChannelKind::Force,
        ChannelKind::Position,
        ChannelKind::PressureA,
        ChannelKind::PressureB,
    ];
    let mut cols: Vec<Vec<f64>> = vec![Vec::with_capacity(n); kinds.len()];
    let mut t = Vec::with_capacity(n);
    for &uk in &u {
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
    let record = Record::from_columns(&format!("synthetic seed {seed}"), t, u, channels, None, 0)
        .expect("generated record is valid");
    Case {
        seed,
        hidden: hidden.to_vec(),
        nominal,
        truth,
        record,
    }
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
            ChannelKind::Force => Some((c.kind, 0.05 * crate::replay::std(&c.values))),
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
