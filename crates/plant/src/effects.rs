//! The effect catalogue of DESIGN.md: stable ids shared by configs, diagnosis and tests.

use crate::params::Effects;

/// One effect of the catalogue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectId {
    /// Static + Coulomb + viscous + Stribeck seal friction (001, 003 eq. 5, 004 eq. 28–34).
    Friction,
    /// Spool overlap / dead zone / zero offset (002, 003, 004).
    ValveDeadband,
    /// Spool travel or flow limit (002, 004).
    ValveSaturation,
    /// Spool dynamics (000, 002, 003, 004).
    ValveDynamics,
    /// Cross-piston leakage (003 k_l, 004 C_in).
    InternalLeakage,
    /// Leakage to tank (003 k_le).
    ExternalLeakage,
    /// Pressure-dependent bulk modulus (002 eq. 35–36).
    BulkModulusPressure,
    /// Lines between valve and cylinder (001, 002 eq. 9–17).
    LineDynamics,
    /// Compliant connection to a load mass (003 SDD).
    FlexibleMount,
    /// Transport / communication delay.
    TimeDelay,
    /// Periodic disturbance on a sensor (004).
    SensorTone,
    /// Supply pressure sags with flow (000).
    SupplyPressureDrop,
}

impl EffectId {
    /// Every effect, in catalogue order.
    pub const ALL: [EffectId; 12] = [
        EffectId::Friction,
        EffectId::ValveDeadband,
        EffectId::ValveSaturation,
        EffectId::ValveDynamics,
        EffectId::InternalLeakage,
        EffectId::ExternalLeakage,
        EffectId::BulkModulusPressure,
        EffectId::LineDynamics,
        EffectId::FlexibleMount,
        EffectId::TimeDelay,
        EffectId::SensorTone,
        EffectId::SupplyPressureDrop,
    ];

    /// The stable id string.
    pub fn as_str(self) -> &'static str {
        match self {
            EffectId::Friction => "friction",
            EffectId::ValveDeadband => "valve_deadband",
            EffectId::ValveSaturation => "valve_saturation",
            EffectId::ValveDynamics => "valve_dynamics",
            EffectId::InternalLeakage => "internal_leakage",
            EffectId::ExternalLeakage => "external_leakage",
            EffectId::BulkModulusPressure => "bulk_modulus_pressure",
            EffectId::LineDynamics => "line_dynamics",
            EffectId::FlexibleMount => "flexible_mount",
            EffectId::TimeDelay => "time_delay",
            EffectId::SensorTone => "sensor_tone",
            EffectId::SupplyPressureDrop => "supply_pressure_drop",
        }
    }

    /// Parse an id string.
    pub fn parse(s: &str) -> Option<EffectId> {
        EffectId::ALL.iter().copied().find(|e| e.as_str() == s)
    }
}

impl std::fmt::Display for EffectId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Effects {
    /// Whether an effect is present and enabled.
    pub fn is_enabled(&self, id: EffectId) -> bool {
        match id {
            EffectId::Friction => self.friction.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveDeadband => self.valve_deadband.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveSaturation => self.valve_saturation.as_ref().is_some_and(|e| e.enabled),
            EffectId::ValveDynamics => self.valve_dynamics.as_ref().is_some_and(|e| e.enabled),
            EffectId::InternalLeakage => self.internal_leakage.as_ref().is_some_and(|e| e.enabled),
            EffectId::ExternalLeakage => self.external_leakage.as_ref().is_some_and(|e| e.enabled),
            EffectId::BulkModulusPressure => self
                .bulk_modulus_pressure
                .as_ref()
                .is_some_and(|e| e.enabled),
            EffectId::LineDynamics => self.line_dynamics.as_ref().is_some_and(|e| e.enabled),
            EffectId::FlexibleMount => self.flexible_mount.as_ref().is_some_and(|e| e.enabled),
            EffectId::TimeDelay => self.time_delay.as_ref().is_some_and(|e| e.enabled),
            EffectId::SensorTone => self.sensor_tone.as_ref().is_some_and(|e| e.enabled),
            EffectId::SupplyPressureDrop => self
                .supply_pressure_drop
                .as_ref()
                .is_some_and(|e| e.enabled),
        }
    }

    /// Ids of every enabled effect.
    pub fn enabled(&self) -> Vec<EffectId> {
        EffectId::ALL
            .iter()
            .copied()
            .filter(|e| self.is_enabled(*e))
            .collect()
    }
}

/// Bulk modulus of an oil with entrained air (Pa) at gauge pressure `p` (Pa): liquid β₀,
/// air volume fraction α₀ at atmospheric pressure, polytropic index n (the "Yu" model of
/// Gholizadeh, Burton & Schoenau 2011, Int. J. Fluid Power 12(3), eq. 20; Yu, Chen & Lu 1994):
/// β = [(1−α₀) + α₀(P₀/P)^(1/n)] / [(1−α₀)/β₀ + α₀(P₀/P)^(1/n)/(n·P)], P = p + P₀ absolute,
/// floored at 0.2·P₀ (cavitation: the formula is not meant below that).
#[inline]
pub fn entrained_air_bulk_modulus(beta0: f64, alpha0: f64, n: f64, p: f64) -> f64 {
    const P0: f64 = 101_325.0;
    let pa = (p + P0).max(0.2 * P0);
    let air = alpha0 * (P0 / pa).powf(1.0 / n);
    ((1.0 - alpha0) + air) / ((1.0 - alpha0) / beta0 + air / (n * pa))
}

/// Supply model of `supply_pressure_drop` (Pa, m³/s): one substep of the supply pressure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SupplyModel {
    /// p_s → p_s0 − R·Q_s with time constant τ (000), exact for Q_s held over the substep.
    Resistance {
        /// Setting p_s0 (Pa).
        ps0: f64,
        /// R (Pa·s/m³).
        r: f64,
        /// τ (s).
        tau: f64,
    },
    /// Flow-limited pressure-compensated pump into a volume (see
    /// [`crate::params::SupplyVariant::PumpLimit`]).
    PumpLimit {
        /// Setting p_s0 (Pa).
        ps0: f64,
        /// Q_max (m³/s).
        qmax: f64,
        /// Regulation band Δp_c (Pa).
        band: f64,
        /// Capacitance V/β₀ (m³/Pa).
        cap: f64,
    },
}

impl SupplyModel {
    /// From the effect section and the nominal supply pressure / fluid β₀.
    pub fn new(s: &crate::params::SupplyPressureDrop, ps0: f64, beta0: f64) -> Self {
        match s.variant {
            crate::params::SupplyVariant::Resistance => SupplyModel::Resistance {
                ps0,
                r: s.resistance,
                tau: s.time_constant,
            },
            crate::params::SupplyVariant::PumpLimit => SupplyModel::PumpLimit {
                ps0,
                qmax: s.max_flow,
                band: s.regulation_band,
                cap: s.volume / beta0,
            },
        }
    }

    /// Equivalent droop resistance (Pa·s/m³): R, or Δp_c/Q_max of the pump's compensator.
    pub fn droop(&self) -> f64 {
        match *self {
            SupplyModel::Resistance { r, .. } => r,
            SupplyModel::PumpLimit { qmax, band, .. } => band / qmax.max(1e-300),
        }
    }

    /// Advance the supply pressure `ps` (Pa) over substep `h` (s) with the valve drawing
    /// `qs` (m³/s) from it; never below the tank pressure `pt`. The pump's compensator band is
    /// linear in p_s and integrated exactly (exponential), the flow-limited part explicitly.
    #[inline]
    pub fn advance(&self, ps: f64, qs: f64, pt: f64, h: f64) -> f64 {
        match *self {
            SupplyModel::Resistance { ps0, r, tau } => {
                let target = (ps0 - r * qs).max(pt);
                ps + (target - ps) * (1.0 - (-h / tau).exp())
            }
            SupplyModel::PumpLimit {
                ps0,
                qmax,
                band,
                cap,
            } => {
                let p_full = ps0 - band;
                let next = if ps > p_full {
                    // Within the band: C·ṗ = Q_max·(p_s0 − p)/Δp_c − q_s, exact.
                    let target = ps0 - band * qs / qmax;
                    let tau = band * cap / qmax;
                    target + (ps - target) * (-h / tau).exp()
                } else {
                    ps + h * (qmax - qs) / cap
                };
                next.clamp(pt, ps0)
            }
        }
    }
}

/// One substep of a compliant cylinder mount (`flexible_mount`, variant `piston_side`):
/// advances the body displacement `xb` (m) and velocity `vb` (m/s) with the reaction
/// `f_rel` (N) of the forces the oil and seals put on the piston (implicit in the mount's
/// damping), and returns the body's acceleration (m/s²) over the substep.
#[inline]
pub fn body_mount_step(
    xb: &mut f64,
    vb: &mut f64,
    f_rel: f64,
    (mb, km, dm): (f64, f64, f64),
    h: f64,
) -> f64 {
    let v_new = (mb * *vb + h * (-f_rel - km * *xb)) / (mb + h * dm);
    let a = (v_new - *vb) / h;
    *vb = v_new;
    *xb += h * v_new;
    a
}

/// Cross-field checks of the effect variants (issue 17): each variant's own parameters must
/// be given and admissible.
pub fn validate_variants(p: &crate::params::PlantParams) -> Result<(), crate::spec::ConfigError> {
    use crate::params::*;
    use crate::spec::ConfigError;
    p.refit_ranges()?;
    let e = &p.effects;
    if let Some(l) = e.internal_leakage.as_ref() {
        if l.variant != LeakageVariant::Equal {
            return Err(ConfigError::new(
                "effects.internal_leakage.variant",
                "cross-piston leakage has one coefficient; expected \"equal\" (per-chamber leakage to tank is external_leakage.variant = \"per_chamber\")",
            ));
        }
    }
    if let Some(b) = e.bulk_modulus_pressure.as_ref() {
        if b.variant == BulkVariant::EntrainedAir && !(b.air_fraction > 0.0) {
            return Err(ConfigError::new(
                "effects.bulk_modulus_pressure.air_fraction",
                "must be > 0 (volume fraction of air at atmospheric pressure, -) for variant = \"entrained_air\"",
            ));
        }
    }
    if let Some(s) = e.supply_pressure_drop.as_ref() {
        match s.variant {
            SupplyVariant::Resistance if !(s.time_constant > 0.0) => {
                return Err(ConfigError::new(
                    "effects.supply_pressure_drop.time_constant",
                    "must be > 0 s for variant = \"resistance\"",
                ))
            }
            SupplyVariant::PumpLimit
                if !(s.max_flow > 0.0 && s.regulation_band > 0.0 && s.volume > 0.0) =>
            {
                return Err(ConfigError::new(
                    "effects.supply_pressure_drop",
                    format!(
                        "variant = \"pump_limit\" needs max_flow > 0 m³/s, regulation_band > 0 Pa and volume > 0 m³; got {} m³/s, {} Pa, {} m³",
                        s.max_flow, s.regulation_band, s.volume
                    ),
                ))
            }
            _ => {}
        }
    }
    if let Some(t) = e.sensor_tone.as_ref() {
        if !t.phases.is_empty() && t.phases.len() != t.frequencies.len() {
            return Err(ConfigError::new(
                "effects.sensor_tone.phases",
                format!(
                    "{} phases for {} frequencies; expected one phase (rad) per frequency or none",
                    t.phases.len(),
                    t.frequencies.len()
                ),
            ));
        }
    }
    Ok(())
}
