//! Free parameters of the nominal model and of every catalogue effect, and a bounded
//! Nelder–Mead minimiser working in normalised (optionally logarithmic) coordinates.

use crate::analysis::Analysis;
use crate::data::Record;
use ehactl_plant::params::{
    BulkModulusPressure, BulkVariant, DeadbandVariant, FlexibleMount, Friction, FrictionVariant,
    Leakage, LeakageVariant, LineDynamics, MountVariant, SaturationVariant, SensorChannel,
    SensorTone, SupplyPressureDrop, SupplyVariant, TimeDelay, ValveDeadband, ValveDynamics,
    ValveSaturation,
};
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// Writes a free parameter's value into the plant parameters.
pub type Setter = Arc<dyn Fn(&mut PlantParams, f64) + Send + Sync>;

/// One free parameter: dotted config path, bounds (SI), scale, start value and how to set it.
#[derive(Clone)]
pub struct FreeParam {
    /// Dotted config path (or `<path>/nominal` for a factor on the nominal value).
    pub name: String,
    /// Lower bound (SI or factor).
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
    /// Search in log space (bounds must be > 0).
    pub log: bool,
    /// Start value.
    pub init: f64,
    /// Writes the value into the parameters.
    pub set: Setter,
}

impl std::fmt::Debug for FreeParam {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ∈ [{}, {}]", self.name, self.lo, self.hi)
    }
}

impl FreeParam {
    fn new(name: &str, lo: f64, hi: f64, log: bool, init: f64, set: Setter) -> Self {
        // Bounds derived from the data (e.g. a tone frequency up to Nyquist) can cross on
        // odd records: the parameter is then pinned at `lo` instead of panicking in clamp.
        let hi = if hi >= lo { hi } else { lo };
        Self {
            name: name.to_string(),
            lo,
            hi,
            log,
            init: init.clamp(lo, hi),
            set,
        }
    }
    /// Value → normalised coordinate in [0, 1].
    pub fn to_unit(&self, v: f64) -> f64 {
        let v = v.clamp(self.lo, self.hi);
        if self.hi <= self.lo {
            return 0.0;
        }
        if self.log {
            (v / self.lo).ln() / (self.hi / self.lo).ln()
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }
    /// Normalised coordinate → value.
    pub fn from_unit(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, 1.0);
        if self.log {
            self.lo * (self.hi / self.lo).powf(s)
        } else {
            self.lo + s * (self.hi - self.lo)
        }
    }
}

/// Scales of the rig used to bound effect parameters.
#[derive(Debug, Clone, Copy)]
pub struct Scales {
    /// Supply pressure × cap area (N).
    pub force: f64,
    /// Edge flow at full opening and Δp = p_s/2 (m³/s).
    pub flow: f64,
    /// Supply pressure (Pa).
    pub pressure: f64,
    /// Moving mass (kg).
    pub mass: f64,
    /// Hydraulic stiffness at the initial position (N/m).
    pub stiffness: f64,
    /// Sample period (s).
    pub dt: f64,
}

impl Scales {
    /// Derive from the nominal parameters and the record.
    pub fn new(p: &PlantParams, rec: &Record) -> Self {
        let law = ehactl_plant::valve::EdgeLaw::new(p);
        let ps = p.supply.pressure - p.supply.tank_pressure;
        let flow = law.k * (0.5 * ps).powf(law.n);
        let stiffness = ehactl_plant::Plant::configure(p, rec.dt)
            .map(|pl| pl.hydraulic_stiffness(p.cylinder.initial_position))
            .unwrap_or(1e7)
            + p.mechanics.load_stiffness;
        Self {
            force: ps * p.cylinder.area_a,
            flow,
            pressure: ps,
            mass: p.mechanics.mass,
            stiffness,
            dt: rec.dt,
        }
    }
}

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
                    Arc::new(move |p, s| p.set_nominal_value(path, v * s)),
                )
            } else {
                FreeParam::new(
                    path,
                    lo,
                    hi,
                    false,
                    v,
                    Arc::new(move |p, x| p.set_nominal_value(path, x)),
                )
            }
        })
        .collect()
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
    let p = FreeParam::new;
    let mut out = Vec::new();
    match e {
        EffectId::Friction => {
            let cur = ef.friction.as_ref().map(|f| f.variant);
            if cur != Some(FrictionVariant::LoadCoulomb) {
                out.push(("stribeck", first));
            }
            if cur.is_none() || cur == Some(FrictionVariant::LoadCoulomb) {
                let c0 = ef
                    .friction
                    .as_ref()
                    .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
                let base = Friction {
                    enabled: true,
                    variant: FrictionVariant::LoadCoulomb,
                    static_force: c0,
                    coulomb_force: c0,
                    stribeck_velocity: 0.005,
                    viscous: 0.0,
                };
                let (a, b) = (base.clone(), base);
                out.push((
                    "load_coulomb",
                    vec![
                        p(
                            "effects.friction.coulomb_force",
                            1e-4 * sc.force,
                            0.1 * sc.force,
                            true,
                            c0,
                            Arc::new(move |p, v| {
                                let f = p.effects.friction.get_or_insert_with(|| a.clone());
                                f.enabled = true;
                                f.variant = FrictionVariant::LoadCoulomb;
                                f.coulomb_force = v;
                                f.static_force = v;
                            }),
                        ),
                        p(
                            "effects.friction.stribeck_velocity",
                            2e-4,
                            0.05,
                            true,
                            0.005,
                            Arc::new(move |p, v| {
                                let f = p.effects.friction.get_or_insert_with(|| b.clone());
                                f.enabled = true;
                                f.variant = FrictionVariant::LoadCoulomb;
                                f.stribeck_velocity = v;
                            }),
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
                let (a, b) = (d0.clone(), d0.clone());
                out.push((
                    "amplifier",
                    vec![
                        p(
                            "effects.valve_deadband.deadzone",
                            0.0,
                            0.3,
                            false,
                            d0.deadzone.max(0.02),
                            Arc::new(move |p, v| {
                                let d = p.effects.valve_deadband.get_or_insert_with(|| a.clone());
                                d.enabled = true;
                                d.variant = DeadbandVariant::Amplifier;
                                d.overlap = 0.0;
                                d.deadzone = v;
                            }),
                        ),
                        p(
                            "effects.valve_deadband.zero_offset",
                            -0.05,
                            0.05,
                            false,
                            d0.zero_offset,
                            Arc::new(move |p, v| {
                                let d = p.effects.valve_deadband.get_or_insert_with(|| b.clone());
                                d.enabled = true;
                                d.variant = DeadbandVariant::Amplifier;
                                d.zero_offset = v;
                            }),
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
                let (a, b) = (s0.clone(), s0.clone());
                out.push((
                    "asymmetric",
                    vec![
                        p(
                            "effects.valve_saturation.spool_limit",
                            0.05,
                            1.0,
                            false,
                            s0.spool_limit.min(0.9),
                            Arc::new(move |p, v| {
                                let s = p.effects.valve_saturation.get_or_insert_with(|| a.clone());
                                s.enabled = true;
                                s.variant = SaturationVariant::Asymmetric;
                                s.spool_limit = v;
                            }),
                        ),
                        p(
                            "effects.valve_saturation.spool_limit_negative",
                            0.05,
                            1.0,
                            false,
                            s0.spool_limit_negative.min(0.9),
                            Arc::new(move |p, v| {
                                let s = p.effects.valve_saturation.get_or_insert_with(|| b.clone());
                                s.enabled = true;
                                s.variant = SaturationVariant::Asymmetric;
                                s.spool_limit_negative = v;
                            }),
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
                let l0 = ef.external_leakage.clone();
                let ia = l0
                    .as_ref()
                    .map_or(0.01 * kc, |l| l.coefficient.max(1e-5 * kc));
                let ib = l0
                    .as_ref()
                    .map_or(0.01 * kc, |l| l.coefficient_b.max(1e-5 * kc));
                let set = |b_side: bool| -> Setter {
                    Arc::new(move |p, v| {
                        let l = p.effects.external_leakage.get_or_insert(Leakage {
                            enabled: true,
                            variant: LeakageVariant::PerChamber,
                            coefficient: 0.0,
                            coefficient_b: 0.0,
                        });
                        l.enabled = true;
                        l.variant = LeakageVariant::PerChamber;
                        if b_side {
                            l.coefficient_b = v;
                        } else {
                            l.coefficient = v;
                        }
                    })
                };
                out.push((
                    "per_chamber",
                    vec![
                        p(
                            "effects.external_leakage.coefficient",
                            1e-5 * kc,
                            kc,
                            true,
                            ia,
                            set(false),
                        ),
                        p(
                            "effects.external_leakage.coefficient_b",
                            1e-5 * kc,
                            kc,
                            true,
                            ib,
                            set(true),
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
                out.push((
                    "entrained_air",
                    vec![p(
                        "effects.bulk_modulus_pressure.air_fraction",
                        1e-5,
                        0.1,
                        true,
                        init,
                        Arc::new(move |p, v| {
                            let b = p
                                .effects
                                .bulk_modulus_pressure
                                .get_or_insert_with(|| b0.clone());
                            b.enabled = true;
                            b.variant = BulkVariant::EntrainedAir;
                            b.air_fraction = v;
                        }),
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
                let set = |which: u8| -> Setter {
                    let s0 = s0.clone();
                    Arc::new(move |p, v| {
                        let s = p
                            .effects
                            .supply_pressure_drop
                            .get_or_insert_with(|| s0.clone());
                        s.enabled = true;
                        s.variant = SupplyVariant::PumpLimit;
                        match which {
                            0 => s.max_flow = v,
                            1 => s.regulation_band = v,
                            _ => s.volume = v,
                        }
                    })
                };
                out.push((
                    "pump_limit",
                    vec![
                        p(
                            "effects.supply_pressure_drop.max_flow",
                            0.2 * sc.flow,
                            4.0 * sc.flow,
                            true,
                            s0.max_flow,
                            set(0),
                        ),
                        p(
                            "effects.supply_pressure_drop.regulation_band",
                            0.005 * sc.pressure,
                            0.5 * sc.pressure,
                            true,
                            s0.regulation_band,
                            set(1),
                        ),
                        p(
                            "effects.supply_pressure_drop.volume",
                            2e-5,
                            1e-2,
                            true,
                            s0.volume,
                            set(2),
                        ),
                    ],
                ));
            }
        }
        _ => out.push(("-", first)),
    }
    out
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
    let p = |name: &str, lo: f64, hi: f64, log: bool, init: f64, set: Setter| {
        FreeParam::new(name, lo, hi, log, init, set)
    };
    Some(match e {
        EffectId::Friction => {
            let f0 = ef.friction.clone().unwrap_or(Friction {
                enabled: true,
                variant: FrictionVariant::Stribeck,
                static_force: 0.0,
                coulomb_force: 0.0,
                stribeck_velocity: 0.01,
                viscous: 0.0,
            });
            fn fr<'a>(p: &'a mut PlantParams, f0: &Friction) -> &'a mut Friction {
                let f = p.effects.friction.get_or_insert_with(|| f0.clone());
                f.enabled = true;
                f
            }
            let (g1, g2, g3) = (f0.clone(), f0.clone(), f0.clone());
            let c0 = ef
                .friction
                .as_ref()
                .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
            let r0 = ef
                .friction
                .as_ref()
                .map_or(1.2, |f| f.static_force / f.coulomb_force.max(1e-9));
            vec![
                p(
                    "effects.friction.coulomb_force",
                    1e-4 * sc.force,
                    0.1 * sc.force,
                    true,
                    c0,
                    Arc::new(move |p, v| {
                        let f = fr(p, &g1);
                        f.coulomb_force = v;
                        f.static_force = v;
                    }),
                ),
                p(
                    "effects.friction.static_force/coulomb_force",
                    1.0,
                    2.5,
                    false,
                    r0,
                    Arc::new(move |p, v| {
                        let f = fr(p, &g2);
                        f.static_force = f.coulomb_force * v;
                    }),
                ),
                p(
                    "effects.friction.stribeck_velocity",
                    1e-3,
                    0.1,
                    true,
                    0.01,
                    Arc::new(move |p, v| fr(p, &g3).stribeck_velocity = v),
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
            let (d1, d2) = (d0.clone(), d0.clone());
            vec![
                p(
                    "effects.valve_deadband.overlap",
                    0.0,
                    0.3,
                    false,
                    d0.overlap.max(0.02),
                    Arc::new(move |p, v| {
                        let d = p.effects.valve_deadband.get_or_insert_with(|| d1.clone());
                        d.enabled = true;
                        d.overlap = v;
                    }),
                ),
                p(
                    "effects.valve_deadband.zero_offset",
                    -0.05,
                    0.05,
                    false,
                    d0.zero_offset,
                    Arc::new(move |p, v| {
                        let d = p.effects.valve_deadband.get_or_insert_with(|| d2.clone());
                        d.enabled = true;
                        d.zero_offset = v;
                    }),
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
            vec![p(
                "effects.valve_saturation.spool_limit",
                0.05,
                1.0,
                false,
                init,
                Arc::new(move |p, v| {
                    let s = p.effects.valve_saturation.get_or_insert_with(|| s0.clone());
                    s.enabled = true;
                    s.spool_limit = v;
                }),
            )]
        }
        EffectId::ValveDynamics => match ef.valve_dynamics.clone() {
            Some(d) if d.order == 1 => {
                vec![p(
                    "effects.valve_dynamics.time_constant",
                    1e-4,
                    0.3,
                    true,
                    d.time_constant,
                    Arc::new(move |p, v| {
                        let s = p.effects.valve_dynamics.get_or_insert_with(|| d.clone());
                        s.enabled = true;
                        s.time_constant = v;
                    }),
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
                let (a, b) = (d0.clone(), d0);
                vec![
                    p(
                        "effects.valve_dynamics.natural_frequency",
                        std::f64::consts::TAU * 1.0,
                        std::f64::consts::TAU * (0.5 / sc.dt).min(3000.0),
                        true,
                        w0,
                        Arc::new(move |p, v| {
                            let s = p.effects.valve_dynamics.get_or_insert_with(|| a.clone());
                            s.enabled = true;
                            s.order = 2;
                            s.natural_frequency = v;
                            if s.damping_ratio <= 0.0 {
                                s.damping_ratio = 0.7;
                            }
                        }),
                    ),
                    p(
                        "effects.valve_dynamics.damping_ratio",
                        0.2,
                        2.0,
                        false,
                        z0,
                        Arc::new(move |p, v| {
                            let s = p.effects.valve_dynamics.get_or_insert_with(|| b.clone());
                            s.enabled = true;
                            s.order = 2;
                            s.damping_ratio = v;
                        }),
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
            let name = if internal {
                "effects.internal_leakage.coefficient"
            } else {
                "effects.external_leakage.coefficient"
            };
            vec![p(
                name,
                1e-5 * kc,
                1.0 * kc,
                true,
                init,
                Arc::new(move |p, v| {
                    let slot = if internal {
                        &mut p.effects.internal_leakage
                    } else {
                        &mut p.effects.external_leakage
                    };
                    let l = slot.get_or_insert(Leakage {
                        enabled: true,
                        variant: LeakageVariant::Equal,
                        coefficient: v,
                        coefficient_b: 0.0,
                    });
                    l.enabled = true;
                    l.coefficient = v;
                }),
            )]
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
            vec![p(
                "effects.bulk_modulus_pressure.slope",
                0.0,
                400.0,
                false,
                init,
                Arc::new(move |p, v| {
                    let b = p
                        .effects
                        .bulk_modulus_pressure
                        .get_or_insert_with(|| cur.clone());
                    b.enabled = true;
                    b.slope = v;
                }),
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
                friction: Default::default(),
            });
            let (a, b) = (cur.clone(), cur.clone());
            vec![
                p(
                    "effects.line_dynamics.length",
                    0.1,
                    15.0,
                    true,
                    cur.length,
                    Arc::new(move |p, v| {
                        let l = p.effects.line_dynamics.get_or_insert_with(|| a.clone());
                        l.enabled = true;
                        l.length = v;
                    }),
                ),
                p(
                    "effects.line_dynamics.diameter",
                    2e-3,
                    3e-2,
                    true,
                    cur.diameter,
                    Arc::new(move |p, v| {
                        let l = p.effects.line_dynamics.get_or_insert_with(|| b.clone());
                        l.enabled = true;
                        l.diameter = v;
                    }),
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
            let (a, b, c) = (base.clone(), base.clone(), base);
            vec![
                p(
                    "effects.flexible_mount.load_mass",
                    0.02 * sc.mass,
                    20.0 * sc.mass,
                    true,
                    m0,
                    Arc::new(move |p, v| {
                        let m = p.effects.flexible_mount.get_or_insert_with(|| a.clone());
                        m.enabled = true;
                        m.load_mass = v;
                    }),
                ),
                p(
                    "effects.flexible_mount.stiffness",
                    1e-3 * sc.stiffness,
                    10.0 * sc.stiffness,
                    true,
                    k0,
                    Arc::new(move |p, v| {
                        let m = p.effects.flexible_mount.get_or_insert_with(|| b.clone());
                        m.enabled = true;
                        m.stiffness = v;
                    }),
                ),
                p(
                    "effects.flexible_mount.damping/critical",
                    0.005,
                    2.0,
                    true,
                    z0,
                    Arc::new(move |p, v| {
                        let m = p.effects.flexible_mount.get_or_insert_with(|| c.clone());
                        m.enabled = true;
                        m.damping = v * 2.0 * (m.stiffness * m.load_mass).sqrt();
                    }),
                ),
            ]
        }
        EffectId::TimeDelay => {
            let cur = ef.time_delay.as_ref().map_or(0.0, |d| d.delay);
            let init = if cur > 0.0 { cur } else { an.lag.max(sc.dt) };
            vec![p(
                "effects.time_delay.delay",
                0.0,
                (60.0 * sc.dt).min(0.2),
                false,
                init,
                Arc::new(move |p, v| {
                    let d = p.effects.time_delay.get_or_insert(TimeDelay {
                        enabled: true,
                        delay: v,
                    });
                    d.enabled = true;
                    d.delay = v;
                }),
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
                v.push(p(
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
                v.push(p(
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
                v.push(p(
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
            let (a, b) = (cur.clone(), cur.clone());
            vec![
                p(
                    "effects.supply_pressure_drop.resistance",
                    1e-3 * r_s,
                    2.0 * r_s,
                    true,
                    cur.resistance,
                    Arc::new(move |p, v| {
                        let s = p
                            .effects
                            .supply_pressure_drop
                            .get_or_insert_with(|| a.clone());
                        s.enabled = true;
                        s.resistance = v;
                    }),
                ),
                p(
                    "effects.supply_pressure_drop.time_constant",
                    1e-3,
                    1.0,
                    true,
                    cur.time_constant,
                    Arc::new(move |p, v| {
                        let s = p
                            .effects
                            .supply_pressure_drop
                            .get_or_insert_with(|| b.clone());
                        s.enabled = true;
                        s.time_constant = v;
                    }),
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
