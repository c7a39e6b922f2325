//! How the synthetic generator ([`crate::synth`]) hides each catalogue effect in a plant
//! config: the effect switched on with parameters drawn from a realistic range for the test
//! bench (`configs/diagnose_testrig.toml`), one function per effect. [`hide`] and
//! [`hide_variant`] are the one table keyed by [`EffectId`] (the match is exhaustive, so a new
//! effect does not build without its hiding). The diagnosis side of each effect is
//! crates/ident/src/effects/; the plant side crates/plant/src/effects/.

use crate::rng::Rng;
use ehactl_plant::params::{
    BulkModulusPressure, FlexibleMount, Friction, FrictionVariant, Leakage, LineDynamics,
    LineVariant, SensorChannel, SensorTone, SupplyPressureDrop, TimeDelay, ValveDeadband,
    ValveDynamics, ValveSaturation,
};
use ehactl_plant::{EffectId, PlantParams};

/// Switch effect `e` on in `p` with parameters drawn from a realistic range for the test bench.
pub fn hide(e: EffectId, p: &mut PlantParams, rng: &mut Rng) {
    match e {
        EffectId::Friction => friction(p, rng),
        EffectId::ValveDeadband => valve_deadband(p, rng),
        EffectId::ValveSaturation => valve_saturation(p, rng),
        EffectId::ValveDynamics => valve_dynamics(p, rng),
        EffectId::InternalLeakage => internal_leakage(p, rng),
        EffectId::ExternalLeakage => external_leakage(p, rng),
        EffectId::BulkModulusPressure => bulk_modulus_pressure(p, rng),
        EffectId::LineDynamics => line_dynamics(p, rng),
        EffectId::FlexibleMount => flexible_mount(p, rng),
        EffectId::TimeDelay => time_delay(p, rng),
        EffectId::SensorTone => sensor_tone(p, rng),
        EffectId::SupplyPressureDrop => supply_pressure_drop(p, rng),
    }
}

/// Switch effect `e` on in `p` in its structural variant `variant` (one of
/// [`crate::synth::VARIANT_CASES`]: friction `lugre`, line dynamics `hose`; any other name,
/// or another effect, its default as [`hide`]).
pub fn hide_variant(e: EffectId, variant: &str, p: &mut PlantParams, rng: &mut Rng) {
    match (e, variant) {
        (EffectId::Friction, "lugre") => friction_lugre(p, rng),
        (EffectId::LineDynamics, "hose") => line_dynamics_hose(p, rng),
        _ => hide(e, p, rng),
    }
}

/// Effect `e` of `p` (switched on) at α of its strength, physically (`alpha` in (0, 1]):
/// friction forces and bristle coefficients, dead bands and their offset, leak coefficients,
/// β slope and air fraction, line length and resistance, delay, tone amplitudes and supply
/// resistance × α; a spool limit's reach beyond it (1 − L) × α; a spool's time scale × α; a
/// mount's stiffness ÷ α at the same damping ratio; a pump's flow limit ÷ α. These are the
/// sizes `crate::limscore` scales the same way, so a detection limit can be checked on a
/// physical effect of known size rather than on a blend of records
/// (`crate::synth::small_effect`), which no smaller effect produces for a mode or a dead band.
pub fn at_strength(e: EffectId, p: &mut PlantParams, alpha: f64) {
    let a = alpha;
    let reach = |l: f64| 1.0 - a * (1.0 - l);
    let ef = &mut p.effects;
    match e {
        EffectId::Friction => {
            if let Some(f) = ef.friction.as_mut() {
                f.coulomb_force *= a;
                f.static_force *= a;
                f.viscous *= a;
                f.bristle_stiffness *= a;
                f.bristle_damping *= a;
            }
        }
        EffectId::ValveDeadband => {
            if let Some(d) = ef.valve_deadband.as_mut() {
                d.overlap *= a;
                d.deadzone *= a;
                d.zero_offset *= a;
            }
        }
        EffectId::ValveSaturation => {
            if let Some(s) = ef.valve_saturation.as_mut() {
                s.spool_limit = reach(s.spool_limit);
                s.spool_limit_negative = reach(s.spool_limit_negative);
            }
        }
        EffectId::ValveDynamics => {
            if let Some(v) = ef.valve_dynamics.as_mut() {
                v.time_constant *= a;
                v.natural_frequency /= a;
            }
        }
        EffectId::InternalLeakage | EffectId::ExternalLeakage => {
            let leak = if e == EffectId::InternalLeakage {
                ef.internal_leakage.as_mut()
            } else {
                ef.external_leakage.as_mut()
            };
            if let Some(l) = leak {
                l.coefficient *= a;
                l.coefficient_b *= a;
            }
        }
        EffectId::BulkModulusPressure => {
            if let Some(b) = ef.bulk_modulus_pressure.as_mut() {
                b.slope *= a;
                b.air_fraction *= a;
            }
        }
        EffectId::LineDynamics => {
            if let Some(l) = ef.line_dynamics.as_mut() {
                l.length *= a;
                l.resistance *= a;
            }
        }
        EffectId::FlexibleMount => {
            if let Some(m) = ef.flexible_mount.as_mut() {
                m.stiffness /= a;
                m.damping /= a.sqrt();
            }
        }
        EffectId::TimeDelay => {
            if let Some(d) = ef.time_delay.as_mut() {
                d.delay *= a;
            }
        }
        EffectId::SensorTone => {
            if let Some(t) = ef.sensor_tone.as_mut() {
                t.amplitudes.iter_mut().for_each(|v| *v *= a);
            }
        }
        EffectId::SupplyPressureDrop => {
            if let Some(s) = ef.supply_pressure_drop.as_mut() {
                s.resistance *= a;
                if s.max_flow > 0.0 {
                    s.max_flow /= a;
                }
            }
        }
    }
}

/// Stribeck friction: Coulomb force 150–400 N, static 1.1–1.6× Coulomb, Stribeck velocity
/// 5–20 mm/s (log-uniform).
fn friction(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
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

/// Seal friction with pre-sliding bristles (Canudas de Wit et al. 1995): pre-sliding range
/// F_C/σ₀ of 20–80 µm (tens of µm on hydraulic cylinder seals, e.g. Yanada & Sekikawa 2008,
/// Tribology International 41), bristle damping 10–50 % of critical.
fn friction_lugre(p: &mut PlantParams, rng: &mut Rng) {
    let mass = p.mechanics.mass;
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

/// Spool overlap per edge 5–12 % of full travel, zero offset within ±1 % of travel.
fn valve_deadband(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.valve_deadband = Some(ValveDeadband {
        enabled: true,
        variant: Default::default(),
        deadzone: 0.0,
        overlap: rng.range(0.05, 0.12),
        zero_offset: rng.range(-0.01, 0.01),
    });
}

/// Symmetric spool limit (the default variant) at 45–70 % of full travel.
fn valve_saturation(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.valve_saturation = Some(ValveSaturation {
        enabled: true,
        variant: Default::default(),
        spool_limit_negative: 1.0,
        spool_limit: rng.range(0.45, 0.7),
        max_flow: 0.0,
    });
}

/// Second-order spool: natural frequency 15–45 Hz, damping ratio 0.5–0.9.
fn valve_dynamics(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.valve_dynamics = Some(ValveDynamics {
        enabled: true,
        order: 2,
        time_constant: 0.0,
        natural_frequency: std::f64::consts::TAU * rng.range(15.0, 45.0),
        damping_ratio: rng.range(0.5, 0.9),
    });
}

/// Laminar cross-piston leakage 2–8·10⁻¹² m³/(s·Pa) (log-uniform).
fn internal_leakage(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.internal_leakage = Some(Leakage {
        enabled: true,
        variant: Default::default(),
        coefficient_b: 0.0,
        coefficient: rng.log_range(2e-12, 8e-12),
    })
}

/// Laminar leakage to tank 2–8·10⁻¹² m³/(s·Pa) (log-uniform).
fn external_leakage(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.external_leakage = Some(Leakage {
        enabled: true,
        variant: Default::default(),
        coefficient_b: 0.0,
        coefficient: rng.log_range(2e-12, 8e-12),
    })
}

/// Bulk modulus rising with pressure: slope dβ/dp 80–200 (-), up to 2.2 GPa.
fn bulk_modulus_pressure(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.bulk_modulus_pressure = Some(BulkModulusPressure {
        enabled: true,
        variant: Default::default(),
        air_fraction: 0.0,
        polytropic_index: 1.4,
        slope: rng.range(80.0, 200.0),
        max: 2.2e9,
    })
}

/// Rigid pipe of 1.5–4 m and 6–10 mm bore, three segments.
fn line_dynamics(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
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

/// A 1.5–4 m hose of 8–13 mm bore, wall compliance 0.6–2.5·10⁻⁹ 1/Pa (β_eff ≈ 0.3–0.8 GPa),
/// fittings 0.5–2·10⁹ Pa·s/m³; three segments (the fit uses two).
fn line_dynamics_hose(p: &mut PlantParams, rng: &mut Rng) {
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

/// Compliant mount: load mass 10–40 kg, stiffness 2–8·10⁶ N/m (log-uniform), damping 5–20 %
/// of critical.
fn flexible_mount(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
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

/// Command delay 3–10 ms.
fn time_delay(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
    ef.time_delay = Some(TimeDelay {
        enabled: true,
        delay: rng.range(0.003, 0.010),
    })
}

/// A tone of 80–300 Hz on the force sensor (20–40 N) or on chamber A's pressure
/// (0.8–1.6 bar), either with probability ½.
fn sensor_tone(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
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

/// Supply line resistance 1.0–2.5·10¹⁰ Pa·s/m³, time constant 10–50 ms (log-uniform).
fn supply_pressure_drop(p: &mut PlantParams, rng: &mut Rng) {
    let ef = &mut p.effects;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Each effect's hiding switches on its own effect and no other (a wrong line in [`hide`]
    /// would plant one effect under another's name).
    #[test]
    fn each_effect_hides_itself_only() {
        let base = crate::synth::testrig().plant;
        for e in EffectId::ALL {
            for variant in ["", "lugre", "hose"] {
                let mut p = base.clone();
                p.effects = Default::default();
                hide_variant(e, variant, &mut p, &mut Rng::new(1));
                for o in EffectId::ALL {
                    assert_eq!(p.effects.is_enabled(o), o == e, "{e} {variant:?} hid {o}");
                }
            }
        }
    }
}
