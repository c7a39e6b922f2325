//! `valve_dynamics`: spool dynamics, PT1 ż = (u − z)/T_z (003 eq. 1) or second order
//! ẍ = ω²(u − x) − 2ζω ẋ (004 eq. 1, 000): the config section [`ValveDynamics`]
//! (`[effects.valve_dynamics]`). Its exact discretisation is `SpoolModel`
//! (crates/plant/src/valve.rs), which reads the whole plant configuration.

use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// `valve_dynamics`: spool dynamics, PT1 (003 eq. 1) or second order (004 eq. 1, 000).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Order of the spool model: 1 (PT1) or 2.
    #[param(unit = "-", range = Within(1.0, 2.0), desc = "spool model order")]
    pub order: u8,
    /// PT1 time constant T_z (s) for order 1; 003: 0.01.
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "PT1 time constant T_z (003)", uncertain(order = 13, to_range_end))]
    pub time_constant: f64,
    /// Natural frequency ω_nv (rad/s) for order 2; 004: 1507.9.
    #[serde(default)]
    #[param(unit = "rad/s", range = Within(0.0, 1.0e6), desc = "spool ω_nv (004: 1507.9)", uncertain(order = 14))]
    pub natural_frequency: f64,
    /// Damping ratio ζ (-) for order 2; 004: 0.59.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "spool damping ratio ζ (004: 0.59)")]
    pub damping_ratio: f64,
}

impl ValveDynamics {
    /// Check of the order and its bandwidth: order 1 with T_z ≥ 0 s (0: ideal spool), order 2 with
    /// ω_nv > 0 rad/s and ζ > 0.
    pub(crate) fn validate_order(&self) -> Result<(), ConfigError> {
        match self.order {
            // 0 is the ideal spool (the limit of the PT1 as T_z → 0, `SpoolModel::Ideal`): the
            // nominal value of a valve bandwidth the diagnosis refits from 0 up.
            1 if !(self.time_constant >= 0.0) => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.time_constant",
                    "must be ≥ 0 s for order = 1 (0: the spool follows the command at once)",
                ))
            }
            2 if self.natural_frequency <= 0.0 || self.damping_ratio <= 0.0 => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.natural_frequency",
                    "natural_frequency (rad/s) and damping_ratio (-) must be > 0 for order = 2",
                ))
            }
            1 | 2 => {}
            o => {
                return Err(ConfigError::new(
                    "effects.valve_dynamics.order",
                    format!("order {o} is not supported; expected 1 or 2"),
                ))
            }
        }
        Ok(())
    }
}

/// The spool's bandwidth (rad/s) that sets the substep of `integration.method =
/// "linear_exact"`, where the spool is the fastest part integrated explicitly
/// (`Plant::configure`, crates/plant/src/model.rs): 1/T_z (order 1 with T_z > 0), ω_nv
/// (order 2), 0 for an ideal spool (section absent or switched off, or T_z = 0).
pub(crate) fn bandwidth(s: Option<&ValveDynamics>) -> f64 {
    match s.filter(|d| d.enabled) {
        Some(d) if d.order == 1 && d.time_constant > 0.0 => 1.0 / d.time_constant,
        Some(d) if d.order == 2 => d.natural_frequency,
        _ => 0.0,
    }
}
