//! Free parameters of the nominal model and of every catalogue effect, and a bounded
//! Nelder–Mead minimiser working in normalised (optionally logarithmic) coordinates.

use crate::analysis::Analysis;
use crate::freeparam::{seeded, write};
pub use crate::freeparam::{FreeParam, Scales, Setter};
use ehactl_plant::params::{
    BulkModulusPressure, BulkVariant, DeadbandVariant, FlexibleMount, Friction, FrictionVariant,
    Leakage, LeakageVariant, LineDynamics, LineVariant, MountVariant, SaturationVariant,
    SensorChannel, SensorTone, SupplyPressureDrop, SupplyVariant, TimeDelay, ValveDeadband,
    ValveDynamics, ValveSaturation,
};
use ehactl_plant::spec::ParamTree;
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// Nominal parameters refit with every hypothesis, within the uncertainty the config states
/// for them (`[uncertainty]`, [`PlantParams::refit_ranges`]; ±15 % for the valve flow gain,
/// β₀, mass, damping and load stiffness when it is silent), so that realistic errors of the
/// nominal config are not blamed on an effect. Each is a factor on its nominal value
/// (`<path>/nominal`), or the value itself (`<path>`) when the nominal value is 0. A config
/// whose `[uncertainty]` is invalid gives no refit parameters (it fails validation first).
pub fn base_params(nominal: &PlantParams) -> Vec<FreeParam> {
    let ranges = nominal.refit_ranges().unwrap_or_default();
    ranges
        .into_iter()
        .map(|(path, v, lo, hi)| {
            if v != 0.0 {
                FreeParam::new(
                    &format!("{path}/nominal"),
                    lo / v,
                    hi / v,
                    false,
                    1.0,
                    write_nominal(path, move |s| v * s),
                )
            } else {
                FreeParam::new(path, lo, hi, false, v, write_nominal(path, |x| x))
            }
        })
        .collect()
}

/// Setter of a nominal parameter (`UNCERTAIN_PARAMS` path, always present) through the
/// declared-parameter accessor; `value` maps the free coordinate to the parameter value.
fn write_nominal(path: &'static str, value: impl Fn(f64) -> f64 + Send + Sync + 'static) -> Setter {
    debug_assert!(
        PlantParams::knows(path),
        "{path} is not a declared parameter"
    );
    Arc::new(move |p, s| {
        let written = p.set_path(path, value(s));
        debug_assert!(written.is_ok(), "{written:?}");
    })
}

/// The structural variants of effect `e` to fit (DIAGNOSIS.md "Effect variants"): variant
/// name (`-` for effects with one form) and its free parameters. Empty when the effect cannot
/// be tested on this record (e.g. a tone with no line in any residual spectrum). When the
/// nominal config already has the effect, only its configured variant is refit.
pub fn effect_variants(
    e: EffectId,
    nominal: &PlantParams,
    sc: &Scales,
    an: &Analysis,
) -> Vec<(&'static str, Vec<FreeParam>)> {
    let ef = &nominal.effects;
    let Some(first) = effect_params(e, nominal, sc, an) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    match e {
        EffectId::Friction => {
            let cur = ef.friction.as_ref().map(|f| f.variant);
            if cur.is_none() || cur == Some(FrictionVariant::Stribeck) {
                out.push(("stribeck", first));
            }
            if cur.is_none() || cur == Some(FrictionVariant::Lugre) {
                out.push(("lugre", lugre_params(nominal, sc)));
            }
            if cur.is_none() || cur == Some(FrictionVariant::LoadCoulomb) {
                let c0 = ef
                    .friction
                    .as_ref()
                    .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
                let seed = seeded(nominal, |e| {
                    e.friction = Some(Friction {
                        enabled: true,
                        variant: FrictionVariant::LoadCoulomb,
                        static_force: c0,
                        coulomb_force: c0,
                        stribeck_velocity: 0.005,
                        viscous: 0.0,
                        bristle_stiffness: 0.0,
                        bristle_damping: 0.0,
                    })
                });
                let variant = |p: &mut PlantParams| {
                    if let Some(f) = p.effects.friction.as_mut() {
                        f.variant = FrictionVariant::LoadCoulomb;
                    }
                };
                out.push((
                    "load_coulomb",
                    vec![
                        // No stick: the breakaway force equals the Coulomb force.
                        FreeParam::at_then(
                            "effects.friction.coulomb_force",
                            (1e-4 * sc.force, 0.1 * sc.force, true, c0),
                            &seed,
                            move |p| {
                                variant(p);
                                if let Some(f) = p.effects.friction.as_mut() {
                                    f.static_force = f.coulomb_force;
                                }
                            },
                        ),
                        FreeParam::at_then(
                            "effects.friction.stribeck_velocity",
                            (2e-4, 0.05, true, 0.005),
                            &seed,
                            variant,
                        ),
                    ],
                ));
            }
        }
        EffectId::ValveDeadband => {
            let cur = ef.valve_deadband.as_ref().map(|d| d.variant);
            if cur != Some(DeadbandVariant::Amplifier) {
                out.push(("overlap", first));
            }
            if cur.is_none() || cur == Some(DeadbandVariant::Amplifier) {
                let d0 = ef.valve_deadband.clone().unwrap_or(ValveDeadband {
                    enabled: true,
                    variant: DeadbandVariant::Amplifier,
                    deadzone: 0.0,
                    overlap: 0.0,
                    zero_offset: 0.0,
                });
                let (dz, zo) = (d0.deadzone.max(0.02), d0.zero_offset);
                let seed = seeded(nominal, |e| e.valve_deadband = Some(d0));
                let variant = |p: &mut PlantParams| {
                    if let Some(d) = p.effects.valve_deadband.as_mut() {
                        d.variant = DeadbandVariant::Amplifier;
                    }
                };
                out.push((
                    "amplifier",
                    vec![
                        // The amplifier's dead zone sits ahead of an underlapped spool.
                        FreeParam::at_then(
                            "effects.valve_deadband.deadzone",
                            (0.0, 0.3, false, dz),
                            &seed,
                            move |p| {
                                variant(p);
                                if let Some(d) = p.effects.valve_deadband.as_mut() {
                                    d.overlap = 0.0;
                                }
                            },
                        ),
                        FreeParam::at_then(
                            "effects.valve_deadband.zero_offset",
                            (-0.05, 0.05, false, zo),
                            &seed,
                            variant,
                        ),
                    ],
                ));
            }
        }
        EffectId::ValveSaturation => {
            let cur = ef.valve_saturation.as_ref().map(|d| d.variant);
            if cur != Some(SaturationVariant::Asymmetric) {
                out.push(("symmetric", first));
            }
            if cur.is_none() || cur == Some(SaturationVariant::Asymmetric) {
                let s0 = ef.valve_saturation.clone().unwrap_or(ValveSaturation {
                    enabled: true,
                    variant: SaturationVariant::Asymmetric,
                    spool_limit: 1.0,
                    spool_limit_negative: 1.0,
                    max_flow: 0.0,
                });
                let (pos, neg) = (s0.spool_limit.min(0.9), s0.spool_limit_negative.min(0.9));
                let seed = seeded(nominal, |e| e.valve_saturation = Some(s0));
                let variant = |p: &mut PlantParams| {
                    if let Some(s) = p.effects.valve_saturation.as_mut() {
                        s.variant = SaturationVariant::Asymmetric;
                    }
                };
                out.push((
                    "asymmetric",
                    vec![
                        FreeParam::at_then(
                            "effects.valve_saturation.spool_limit",
                            (0.05, 1.0, false, pos),
                            &seed,
                            variant,
                        ),
                        FreeParam::at_then(
                            "effects.valve_saturation.spool_limit_negative",
                            (0.05, 1.0, false, neg),
                            &seed,
                            variant,
                        ),
                    ],
                ));
            }
        }
        EffectId::ExternalLeakage => {
            let cur = ef.external_leakage.as_ref().map(|d| d.variant);
            if cur != Some(LeakageVariant::PerChamber) {
                out.push(("equal", first));
            }
            if cur.is_none() || cur == Some(LeakageVariant::PerChamber) {
                let kc = sc.flow / sc.pressure;
                let l0 = ef.external_leakage.as_ref();
                let ia = l0.map_or(0.01 * kc, |l| l.coefficient.max(1e-5 * kc));
                let ib = l0.map_or(0.01 * kc, |l| l.coefficient_b.max(1e-5 * kc));
                let seed = seeded(nominal, |e| {
                    e.external_leakage = Some(Leakage {
                        enabled: true,
                        variant: LeakageVariant::PerChamber,
                        coefficient: 0.0,
                        coefficient_b: 0.0,
                    })
                });
                let variant = |p: &mut PlantParams| {
                    if let Some(l) = p.effects.external_leakage.as_mut() {
                        l.variant = LeakageVariant::PerChamber;
                    }
                };
                out.push((
                    "per_chamber",
                    vec![
                        FreeParam::at_then(
                            "effects.external_leakage.coefficient",
                            (1e-5 * kc, kc, true, ia),
                            &seed,
                            variant,
                        ),
                        FreeParam::at_then(
                            "effects.external_leakage.coefficient_b",
                            (1e-5 * kc, kc, true, ib),
                            &seed,
                            variant,
                        ),
                    ],
                ));
            }
        }
        EffectId::BulkModulusPressure => {
            let cur = ef.bulk_modulus_pressure.as_ref().map(|d| d.variant);
            if cur != Some(BulkVariant::EntrainedAir) {
                out.push(("linear", first));
            }
            if cur.is_none() || cur == Some(BulkVariant::EntrainedAir) {
                let b0 = ef
                    .bulk_modulus_pressure
                    .clone()
                    .unwrap_or(BulkModulusPressure {
                        enabled: true,
                        variant: BulkVariant::EntrainedAir,
                        slope: 0.0,
                        air_fraction: 0.005,
                        polytropic_index: 1.4,
                        max: 2.2e9,
                    });
                let init = b0.air_fraction.max(1e-3);
                let seed = seeded(nominal, |e| e.bulk_modulus_pressure = Some(b0));
                out.push((
                    "entrained_air",
                    vec![FreeParam::at_then(
                        "effects.bulk_modulus_pressure.air_fraction",
                        (1e-5, 0.1, true, init),
                        &seed,
                        |p| {
                            if let Some(b) = p.effects.bulk_modulus_pressure.as_mut() {
                                b.variant = BulkVariant::EntrainedAir;
                            }
                        },
                    )],
                ));
            }
        }
        EffectId::FlexibleMount => {
            let cur = ef.flexible_mount.as_ref().map(|d| d.variant);
            if cur.is_none() {
                // Same parameters, the other structure: the body of the cylinder on the mount.
                let body: Vec<FreeParam> = first
                    .iter()
                    .map(|fp| {
                        let set = fp.set.clone();
                        let mut q = fp.clone();
                        q.set = Arc::new(move |p, v| {
                            set(p, v);
                            if let Some(m) = p.effects.flexible_mount.as_mut() {
                                m.variant = MountVariant::PistonSide;
                            }
                        });
                        q
                    })
                    .collect();
                out.push(("load_side", first));
                out.push(("piston_side", body));
            } else {
                let v = if cur == Some(MountVariant::PistonSide) {
                    "piston_side"
                } else {
                    "load_side"
                };
                out.push((v, first));
            }
        }
        EffectId::SupplyPressureDrop => {
            let cur = ef.supply_pressure_drop.as_ref().map(|d| d.variant);
            if cur != Some(SupplyVariant::PumpLimit) {
                out.push(("resistance", first));
            }
            if cur.is_none() || cur == Some(SupplyVariant::PumpLimit) {
                let s0 = ef
                    .supply_pressure_drop
                    .clone()
                    .unwrap_or(SupplyPressureDrop {
                        enabled: true,
                        variant: SupplyVariant::PumpLimit,
                        resistance: 0.0,
                        time_constant: 0.0,
                        max_flow: sc.flow,
                        regulation_band: 0.05 * sc.pressure,
                        volume: 5e-4,
                    });
                let (q0, band0, v0) = (s0.max_flow, s0.regulation_band, s0.volume);
                let seed = seeded(nominal, |e| e.supply_pressure_drop = Some(s0));
                let variant = |p: &mut PlantParams| {
                    if let Some(s) = p.effects.supply_pressure_drop.as_mut() {
                        s.variant = SupplyVariant::PumpLimit;
                    }
                };
                out.push((
                    "pump_limit",
                    vec![
                        FreeParam::at_then(
                            "effects.supply_pressure_drop.max_flow",
                            (0.2 * sc.flow, 4.0 * sc.flow, true, q0),
                            &seed,
                            variant,
                        ),
                        FreeParam::at_then(
                            "effects.supply_pressure_drop.regulation_band",
                            (0.005 * sc.pressure, 0.5 * sc.pressure, true, band0),
                            &seed,
                            variant,
                        ),
                        FreeParam::at_then(
                            "effects.supply_pressure_drop.volume",
                            (2e-5, 1e-2, true, v0),
                            &seed,
                            variant,
                        ),
                    ],
                ));
            }
        }
        EffectId::LineDynamics => {
            let cur = ef.line_dynamics.as_ref().map(|l| l.variant);
            if cur.is_none() || cur == Some(LineVariant::Pipe) {
                out.push(("pipe", first));
            }
            if cur.is_none() || cur == Some(LineVariant::Hose) {
                out.push(("hose", hose_params(nominal, sc)));
            }
        }
        _ => out.push(("-", first)),
    }
    out
}

/// Free parameters of `friction` variant `lugre` (pre-sliding bristles, Canudas de Wit et al.
/// 1995): Coulomb level, breakaway ratio F_s/F_C, Stribeck velocity, bristle stiffness σ₀
/// (bounded by the rig's hydraulic stiffness: 10⁻³…10×) and bristle damping as a ratio ζ of
/// the critical 2·√(σ₀·m) of the moving mass.
fn lugre_params(nominal: &PlantParams, sc: &Scales) -> Vec<FreeParam> {
    let f0 = nominal.effects.friction.clone();
    let c0 = f0
        .as_ref()
        .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
    let r0 = f0.as_ref().map_or(1.2, |f| {
        (f.static_force / f.coulomb_force.max(1e-9)).clamp(1.0, 2.5)
    });
    let vs0 = f0.as_ref().map_or(0.01, |f| f.stribeck_velocity);
    let s0 = f0
        .as_ref()
        .filter(|f| f.bristle_stiffness > 0.0)
        .map_or(0.3 * sc.stiffness, |f| f.bristle_stiffness);
    let z0 = f0
        .as_ref()
        .filter(|f| f.bristle_stiffness > 0.0)
        .map_or(0.2, |f| {
            f.bristle_damping / (2.0 * (f.bristle_stiffness * nominal.mechanics.mass).sqrt())
        });
    let seed = seeded(nominal, |e| {
        e.friction = Some(Friction {
            enabled: true,
            variant: FrictionVariant::Lugre,
            static_force: r0 * c0,
            coulomb_force: c0,
            stribeck_velocity: vs0,
            viscous: f0.as_ref().map_or(0.0, |f| f.viscous),
            bristle_stiffness: s0,
            bristle_damping: 0.0,
        })
    });
    let variant = |p: &mut PlantParams| {
        if let Some(f) = p.effects.friction.as_mut() {
            f.variant = FrictionVariant::Lugre;
        }
    };
    vec![
        // The Coulomb level moves the breakaway force with it (ratio set by the next).
        FreeParam::at_then(
            "effects.friction.coulomb_force",
            (1e-4 * sc.force, 0.1 * sc.force, true, c0),
            &seed,
            move |p| {
                variant(p);
                if let Some(f) = p.effects.friction.as_mut() {
                    f.static_force = f.coulomb_force;
                }
            },
        ),
        // A ratio, not a declared parameter: the value written is scaled to F_s = ratio·F_C.
        FreeParam::new(
            "effects.friction.static_force/coulomb_force",
            1.0,
            2.5,
            false,
            r0,
            write("effects.friction.static_force", &seed, move |p| {
                variant(p);
                if let Some(f) = p.effects.friction.as_mut() {
                    f.static_force *= f.coulomb_force;
                }
            }),
        ),
        FreeParam::at_then(
            "effects.friction.stribeck_velocity",
            (1e-3, 0.1, true, vs0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.friction.bristle_stiffness",
            (1e-3 * sc.stiffness, 10.0 * sc.stiffness, true, s0),
            &seed,
            variant,
        ),
        // A damping ratio, not a declared parameter: the value written is scaled to
        // σ₁ = ζ·2√(σ₀·m) with the (refit) moving mass.
        FreeParam::new(
            "effects.friction.bristle_damping/critical",
            0.01,
            2.0,
            true,
            z0.clamp(0.01, 2.0),
            write("effects.friction.bristle_damping", &seed, move |p| {
                variant(p);
                let m = p.mechanics.mass;
                if let Some(f) = p.effects.friction.as_mut() {
                    f.bristle_damping *= 2.0 * (f.bristle_stiffness * m).sqrt();
                }
            }),
        ),
    ]
}

/// Free parameters of `line_dynamics` variant `hose`: hose length per side (its volume at the
/// seed's bore), wall compliance (1/β_eff − 1/β, from 10⁻¹¹ 1/Pa, a steel-braided hose, to
/// 3·10⁻⁸ 1/Pa, β_eff ≈ 30 MPa) and the fittings' laminar resistance (bounded by the rig's
/// p_s/Q scale). Two segments: the hose's first wave mode stays represented.
fn hose_params(nominal: &PlantParams, sc: &Scales) -> Vec<FreeParam> {
    let r_s = sc.pressure / sc.flow;
    let cur = nominal.effects.line_dynamics.clone();
    let base = cur.clone().unwrap_or(LineDynamics {
        enabled: true,
        variant: LineVariant::Hose,
        length: 2.0,
        diameter: 10e-3,
        segments: 2,
        bulk_modulus: None,
        port_volume: 0.0,
        friction: Default::default(),
        wall_compliance: 1e-9,
        resistance: 0.01 * r_s,
    });
    let (l0, w0) = (base.length, base.wall_compliance.max(1e-11));
    let res0 = base.resistance.max(1e-4 * r_s);
    let seed = seeded(nominal, |e| e.line_dynamics = Some(base));
    let variant = |p: &mut PlantParams| {
        if let Some(l) = p.effects.line_dynamics.as_mut() {
            l.variant = LineVariant::Hose;
        }
    };
    vec![
        FreeParam::at_then(
            "effects.line_dynamics.length",
            (0.1, 15.0, true, l0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.line_dynamics.wall_compliance",
            (1e-11, 3e-8, true, w0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.line_dynamics.resistance",
            (1e-4 * r_s, 0.3 * r_s, true, res0),
            &seed,
            variant,
        ),
    ]
}

/// Free parameters of effect `e` in its first (or configured) variant (bounds from the rig
/// scales, start values from the nominal section if it exists, else from the residual
/// analysis). `None` when the effect cannot be tested on this record (e.g. a tone with no
/// line in any residual spectrum). [`effect_variants`] adds the other structures.
pub fn effect_params(
    e: EffectId,
    nominal: &PlantParams,
    sc: &Scales,
    an: &Analysis,
) -> Option<Vec<FreeParam>> {
    let ef = &nominal.effects;
    let at = FreeParam::at;
    Some(match e {
        EffectId::Friction => {
            let seed = seeded(nominal, |e| {
                e.friction.get_or_insert(Friction {
                    enabled: true,
                    variant: FrictionVariant::Stribeck,
                    static_force: 0.0,
                    coulomb_force: 0.0,
                    stribeck_velocity: 0.01,
                    viscous: 0.0,
                    bristle_stiffness: 0.0,
                    bristle_damping: 0.0,
                });
            });
            let c0 = ef
                .friction
                .as_ref()
                .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
            let r0 = ef
                .friction
                .as_ref()
                .map_or(1.2, |f| f.static_force / f.coulomb_force.max(1e-9));
            vec![
                // The Coulomb level moves the breakaway force with it (ratio kept by the next).
                FreeParam::at_then(
                    "effects.friction.coulomb_force",
                    (1e-4 * sc.force, 0.1 * sc.force, true, c0),
                    &seed,
                    |p| {
                        if let Some(f) = p.effects.friction.as_mut() {
                            f.static_force = f.coulomb_force;
                        }
                    },
                ),
                // A ratio, not a declared parameter: the value written is scaled to F_s = ratio·F_C.
                FreeParam::new(
                    "effects.friction.static_force/coulomb_force",
                    1.0,
                    2.5,
                    false,
                    r0,
                    write("effects.friction.static_force", &seed, |p| {
                        if let Some(f) = p.effects.friction.as_mut() {
                            f.static_force *= f.coulomb_force;
                        }
                    }),
                ),
                at(
                    "effects.friction.stribeck_velocity",
                    (1e-3, 0.1, true, 0.01),
                    &seed,
                ),
            ]
        }
        EffectId::ValveDeadband => {
            let d0 = ef.valve_deadband.clone().unwrap_or(ValveDeadband {
                enabled: true,
                variant: DeadbandVariant::Overlap,
                deadzone: 0.0,
                overlap: 0.0,
                zero_offset: 0.0,
            });
            let (overlap, zero_offset) = (d0.overlap.max(0.02), d0.zero_offset);
            let seed = seeded(nominal, |e| e.valve_deadband = Some(d0));
            vec![
                at(
                    "effects.valve_deadband.overlap",
                    (0.0, 0.3, false, overlap),
                    &seed,
                ),
                at(
                    "effects.valve_deadband.zero_offset",
                    (-0.05, 0.05, false, zero_offset),
                    &seed,
                ),
            ]
        }
        EffectId::ValveSaturation => {
            let s0 = ef.valve_saturation.clone().unwrap_or(ValveSaturation {
                enabled: true,
                variant: SaturationVariant::Symmetric,
                spool_limit_negative: 1.0,
                spool_limit: 1.0,
                max_flow: 0.0,
            });
            let init = s0.spool_limit.min(0.9);
            let seed = seeded(nominal, |e| e.valve_saturation = Some(s0));
            vec![at(
                "effects.valve_saturation.spool_limit",
                (0.05, 1.0, false, init),
                &seed,
            )]
        }
        EffectId::ValveDynamics => match ef.valve_dynamics.clone() {
            Some(d) if d.order == 1 => {
                let init = d.time_constant;
                let seed = seeded(nominal, |e| e.valve_dynamics = Some(d));
                vec![at(
                    "effects.valve_dynamics.time_constant",
                    (1e-4, 0.3, true, init),
                    &seed,
                )]
            }
            other => {
                let d0 = other.unwrap_or(ValveDynamics {
                    enabled: true,
                    order: 2,
                    time_constant: 0.0,
                    natural_frequency: 0.0,
                    damping_ratio: 0.7,
                });
                let (w0, z0) = if d0.natural_frequency > 0.0 {
                    (d0.natural_frequency, d0.damping_ratio)
                } else {
                    (std::f64::consts::TAU * (0.1 / sc.dt).min(200.0), 0.7)
                };
                let seed = seeded(nominal, |e| e.valve_dynamics = Some(d0));
                vec![
                    FreeParam::at_then(
                        "effects.valve_dynamics.natural_frequency",
                        (
                            std::f64::consts::TAU * 1.0,
                            std::f64::consts::TAU * (0.5 / sc.dt).min(3000.0),
                            true,
                            w0,
                        ),
                        &seed,
                        |p| {
                            if let Some(s) = p.effects.valve_dynamics.as_mut() {
                                s.order = 2;
                                if s.damping_ratio <= 0.0 {
                                    s.damping_ratio = 0.7;
                                }
                            }
                        },
                    ),
                    FreeParam::at_then(
                        "effects.valve_dynamics.damping_ratio",
                        (0.2, 2.0, false, z0),
                        &seed,
                        |p| {
                            if let Some(s) = p.effects.valve_dynamics.as_mut() {
                                s.order = 2;
                            }
                        },
                    ),
                ]
            }
        },
        EffectId::InternalLeakage | EffectId::ExternalLeakage => {
            let internal = e == EffectId::InternalLeakage;
            let cur = if internal {
                ef.internal_leakage.clone()
            } else {
                ef.external_leakage.clone()
            };
            let kc = sc.flow / sc.pressure;
            let init = cur
                .as_ref()
                .map_or(0.01 * kc, |l| l.coefficient.max(1e-6 * kc));
            let fresh = Leakage {
                enabled: true,
                variant: LeakageVariant::Equal,
                coefficient: init,
                coefficient_b: 0.0,
            };
            let (name, seed) = if internal {
                let s = seeded(nominal, |e| {
                    e.internal_leakage.get_or_insert(fresh);
                });
                ("effects.internal_leakage.coefficient", s)
            } else {
                let s = seeded(nominal, |e| {
                    e.external_leakage.get_or_insert(fresh);
                });
                ("effects.external_leakage.coefficient", s)
            };
            vec![at(name, (1e-5 * kc, 1.0 * kc, true, init), &seed)]
        }
        EffectId::BulkModulusPressure => {
            let b0 = nominal.fluid.bulk_modulus;
            let cur = ef
                .bulk_modulus_pressure
                .clone()
                .unwrap_or(BulkModulusPressure {
                    enabled: true,
                    variant: BulkVariant::Linear,
                    air_fraction: 0.0,
                    polytropic_index: 1.4,
                    slope: 0.0,
                    max: (2.2e9f64).max(1.6 * b0),
                });
            let init = cur.slope.max(5.0);
            let seed = seeded(nominal, |e| e.bulk_modulus_pressure = Some(cur));
            vec![at(
                "effects.bulk_modulus_pressure.slope",
                (0.0, 400.0, false, init),
                &seed,
            )]
        }
        EffectId::LineDynamics => {
            let cur = ef.line_dynamics.clone().unwrap_or(LineDynamics {
                enabled: true,
                length: 1.0,
                diameter: 8e-3,
                segments: 2,
                bulk_modulus: None,
                port_volume: 0.0,
                variant: Default::default(),
                wall_compliance: 0.0,
                resistance: 0.0,
                friction: Default::default(),
            });
            let (l0, d0) = (cur.length, cur.diameter);
            let seed = seeded(nominal, |e| e.line_dynamics = Some(cur));
            vec![
                at("effects.line_dynamics.length", (0.1, 15.0, true, l0), &seed),
                at(
                    "effects.line_dynamics.diameter",
                    (2e-3, 3e-2, true, d0),
                    &seed,
                ),
            ]
        }
        EffectId::FlexibleMount => {
            let cur = ef.flexible_mount.clone();
            let m0 = cur.as_ref().map_or(sc.mass, |m| m.load_mass);
            let w = std::f64::consts::TAU * an.mode_frequency.max(1.0);
            let k0 = cur.as_ref().map_or(
                (m0 * w * w).clamp(1e-3 * sc.stiffness, 10.0 * sc.stiffness),
                |m| m.stiffness,
            );
            let z0 = cur.as_ref().map_or(0.1, |m| {
                m.damping / (2.0 * (m.stiffness * m.load_mass).sqrt())
            });
            let base = cur.unwrap_or(FlexibleMount {
                enabled: true,
                variant: MountVariant::LoadSide,
                load_mass: m0,
                stiffness: k0,
                damping: 0.0,
            });
            let seed = seeded(nominal, |e| e.flexible_mount = Some(base));
            vec![
                at(
                    "effects.flexible_mount.load_mass",
                    (0.02 * sc.mass, 20.0 * sc.mass, true, m0),
                    &seed,
                ),
                at(
                    "effects.flexible_mount.stiffness",
                    (1e-3 * sc.stiffness, 10.0 * sc.stiffness, true, k0),
                    &seed,
                ),
                // A damping ratio, not a declared parameter: the value written is scaled to
                // d_m = ζ·2√(k_m·m_L).
                FreeParam::new(
                    "effects.flexible_mount.damping/critical",
                    0.005,
                    2.0,
                    true,
                    z0,
                    write("effects.flexible_mount.damping", &seed, |p| {
                        if let Some(m) = p.effects.flexible_mount.as_mut() {
                            m.damping = m.damping * 2.0 * (m.stiffness * m.load_mass).sqrt();
                        }
                    }),
                ),
            ]
        }
        EffectId::TimeDelay => {
            let cur = ef.time_delay.as_ref().map_or(0.0, |d| d.delay);
            let init = if cur > 0.0 { cur } else { an.lag.max(sc.dt) };
            let seed = seeded(nominal, |e| {
                e.time_delay.get_or_insert(TimeDelay {
                    enabled: true,
                    delay: init,
                });
            });
            vec![at(
                "effects.time_delay.delay",
                (0.0, (60.0 * sc.dt).min(0.2), false, init),
                &seed,
            )]
        }
        EffectId::SensorTone => {
            let top = an.tones.first()?;
            let ch = match top.channel {
                "force" => SensorChannel::Force,
                "x" => SensorChannel::Position,
                "p_a" => SensorChannel::PressureA,
                "p_b" => SensorChannel::PressureB,
                _ => return None,
            };
            let lines: Vec<_> = an
                .tones
                .iter()
                .filter(|t| t.channel == top.channel)
                .take(2)
                .copied()
                .collect();
            let nt = lines.len();
            let base = SensorTone {
                enabled: true,
                channel: ch,
                frequencies: lines.iter().map(|l| l.frequency).collect(),
                amplitudes: vec![0.0; nt],
                phases: vec![0.0; nt],
            };
            // Frequencies are refined by the analysis to a small fraction of a Welch bin.
            let df = 0.02 / (sc.dt * 1024.0);
            let mut v = Vec::new();
            for (i, l) in lines.iter().enumerate() {
                let (a, b) = (base.clone(), base.clone());
                v.push(FreeParam::new(
                    &format!("effects.sensor_tone.frequencies[{i}]"),
                    (l.frequency - df).max(0.1),
                    l.frequency + df,
                    false,
                    l.frequency,
                    Arc::new(move |p, x| {
                        let t = p.effects.sensor_tone.get_or_insert_with(|| a.clone());
                        t.frequencies[i] = x;
                    }),
                ));
                // Arbitrary phase: a·sin(ωt + φ) = a_s·sin ωt + a_c·cos ωt, with the sine and
                // cosine amplitudes fitted (a = √(a_s² + a_c²), φ = atan2(a_c, a_s)).
                let c = base.clone();
                let set_sc = |t: &mut SensorTone, i: usize, s: Option<f64>, co: Option<f64>| {
                    if t.phases.len() != t.frequencies.len() {
                        t.phases = vec![0.0; t.frequencies.len()];
                    }
                    let (a, ph) = (t.amplitudes[i], t.phases[i]);
                    let (mut a_s, mut a_c) = (a * ph.cos(), a * ph.sin());
                    if let Some(s) = s {
                        a_s = s;
                    }
                    if let Some(co) = co {
                        a_c = co;
                    }
                    t.amplitudes[i] = a_s.hypot(a_c);
                    t.phases[i] = a_c.atan2(a_s);
                };
                v.push(FreeParam::new(
                    &format!("effects.sensor_tone.sine_amplitudes[{i}]"),
                    -4.0 * l.amplitude,
                    4.0 * l.amplitude,
                    false,
                    l.amplitude,
                    Arc::new(move |p, x| {
                        let t = p.effects.sensor_tone.get_or_insert_with(|| b.clone());
                        set_sc(t, i, Some(x), None);
                    }),
                ));
                v.push(FreeParam::new(
                    &format!("effects.sensor_tone.cosine_amplitudes[{i}]"),
                    -4.0 * l.amplitude,
                    4.0 * l.amplitude,
                    false,
                    0.0,
                    Arc::new(move |p, x| {
                        let t = p.effects.sensor_tone.get_or_insert_with(|| c.clone());
                        set_sc(t, i, None, Some(x));
                    }),
                ));
            }
            v
        }
        EffectId::SupplyPressureDrop => {
            let r_s = sc.pressure / sc.flow;
            let cur = ef
                .supply_pressure_drop
                .clone()
                .unwrap_or(SupplyPressureDrop {
                    enabled: true,
                    variant: SupplyVariant::Resistance,
                    resistance: 0.05 * r_s,
                    time_constant: 0.02,
                    max_flow: 0.0,
                    regulation_band: 0.0,
                    volume: 0.0,
                });
            let (r0, t0) = (cur.resistance, cur.time_constant);
            let seed = seeded(nominal, |e| e.supply_pressure_drop = Some(cur));
            vec![
                at(
                    "effects.supply_pressure_drop.resistance",
                    (1e-3 * r_s, 2.0 * r_s, true, r0),
                    &seed,
                ),
                at(
                    "effects.supply_pressure_drop.time_constant",
                    (1e-3, 1.0, true, t0),
                    &seed,
                ),
            ]
        }
    })
}

/// Bounded Nelder–Mead in the unit cube. Returns (best point, best cost, evaluations).
pub fn nelder_mead(
    f: &mut dyn FnMut(&[f64]) -> f64,
    x0: &[f64],
    step: f64,
    max_evals: usize,
    tol: f64,
) -> (Vec<f64>, f64, usize) {
    let n = x0.len();
    let clamp = |x: &mut Vec<f64>| x.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    let mut evals = 0;
    let mut eval = |x: &[f64], evals: &mut usize| {
        *evals += 1;
        let v = f(x);
        if v.is_finite() {
            v
        } else {
            f64::MAX
        }
    };
    if n == 0 {
        let v = eval(x0, &mut evals);
        return (vec![], v, evals);
    }
    let mut simplex: Vec<(Vec<f64>, f64)> = Vec::with_capacity(n + 1);
    let x0v = x0.to_vec();
    let f0 = eval(&x0v, &mut evals);
    simplex.push((x0v.clone(), f0));
    for i in 0..n {
        let mut x = x0v.clone();
        x[i] += if x[i] + step <= 1.0 { step } else { -step };
        clamp(&mut x);
        let fx = eval(&x, &mut evals);
        simplex.push((x, fx));
    }
    while evals < max_evals {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let (best, worst) = (simplex[0].1, simplex[n].1);
        let spread = simplex
            .iter()
            .skip(1)
            .map(|(x, _)| {
                x.iter()
                    .zip(&simplex[0].0)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if (worst - best).abs() <= tol * best.abs().max(1e-12) && spread < 1e-3 {
            break;
        }
        let mut c = vec![0.0; n];
        for (x, _) in &simplex[..n] {
            for j in 0..n {
                c[j] += x[j] / n as f64;
            }
        }
        let pt = |a: f64| -> Vec<f64> {
            let mut x: Vec<f64> = (0..n)
                .map(|j| c[j] + a * (simplex[n].0[j] - c[j]))
                .collect();
            x.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            x
        };
        let xr = pt(-1.0);
        let fr = eval(&xr, &mut evals);
        if fr < simplex[0].1 {
            let xe = pt(-2.0);
            let fe = eval(&xe, &mut evals);
            simplex[n] = if fe < fr { (xe, fe) } else { (xr, fr) };
        } else if fr < simplex[n - 1].1 {
            simplex[n] = (xr, fr);
        } else {
            let (xc, fc) = if fr < simplex[n].1 {
                let x = pt(-0.5);
                let v = eval(&x, &mut evals);
                (x, v)
            } else {
                let x = pt(0.5);
                let v = eval(&x, &mut evals);
                (x, v)
            };
            if fc < simplex[n].1.min(fr) {
                simplex[n] = (xc, fc);
            } else {
                let x0 = simplex[0].0.clone();
                for s in simplex.iter_mut().skip(1) {
                    let x: Vec<f64> =
                        s.0.iter()
                            .zip(&x0)
                            .map(|(a, b)| b + 0.5 * (a - b))
                            .collect();
                    let v = eval(&x, &mut evals);
                    *s = (x, v);
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (x, v) = simplex.swap_remove(0);
    (x, v, evals)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::Peak;

    fn analysis() -> Analysis {
        Analysis {
            nrmse: vec![0.1],
            noise: vec![0.0],
            reversal_ratio: 1.0,
            small_command_ratio: 1.0,
            large_command_ratio: 1.0,
            bias_share: None,
            lag: 1e-3,
            tones: vec![Peak {
                channel: "force",
                frequency: 225.0,
                amplitude: 3.0,
                prominence: 50.0,
            }],
            mode_frequency: 30.0,
            mode_ratio: 2.0,
            prior: Vec::new(),
        }
    }

    /// Every free parameter named by a declared path writes exactly that parameter and
    /// switches its effect on, from every shipped config, with the section present
    /// (configured) and absent (copied from the fit's seed).
    #[test]
    fn every_setter_writes_its_declared_parameter() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut checked = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let nominal = ehactl_config::RigConfig::load(&path).unwrap().plant;
            let sc = Scales {
                force: 1e4,
                flow: 1e-4,
                pressure: 1e7,
                mass: 10.0,
                stiffness: 1e7,
                dt: 2e-4,
            };
            for &e in EffectId::ALL.iter() {
                for (variant, params) in effect_variants(e, &nominal, &sc, &analysis()) {
                    for fp in params {
                        let v = fp.from_unit(0.37);
                        for start in [nominal.clone(), {
                            let mut p = nominal.clone();
                            p.effects = Default::default();
                            p
                        }] {
                            let mut p = start;
                            (fp.set)(&mut p, v);
                            let what = format!("{} {e} {variant} {}", path.display(), fp.name);
                            assert!(p.effects.is_enabled(e), "{what}: not switched on");
                            if !fp.name.contains(['/', '[']) {
                                assert!(PlantParams::knows(&fp.name), "{what}");
                                assert_eq!(p.get_path(&fp.name), Some(v), "{what}");
                                checked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 200, "{checked} checks");
    }
}
