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
