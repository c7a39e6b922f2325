//! `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V), or an
//! amplifier dead zone ahead of the underlapped spool (variant `amplifier`): the config section
//! [`ValveDeadband`] (`[effects.valve_deadband]`). The edge openings it shapes are computed
//! with the valve's other edge parameters in `EdgeLaw` (crates/plant/src/valve.rs).

use super::switch::yes;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `valve_deadband`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeadbandVariant {
    /// Spool overlap: each metering edge opens only after `overlap` of travel (002, 004).
    #[default]
    Overlap,
    /// Dead zone of the valve amplifier ahead of the (underlapped) spool: spool target =
    /// sign(c)·max(|c| − `deadzone`, 0) with c = u/full scale + `zero_offset` (the
    /// amplifier's dead-band setting of proportional-valve electronics, e.g. Bosch Rexroth
    /// VT-VRPA1 "dead band compensation" set to 0; 004 models it as a command dead zone).
    Amplifier,
}

/// `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V), or
/// an amplifier dead zone ahead of the spool (variant `amplifier`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadband {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`overlap` or `amplifier`).
    #[serde(default)]
    #[param(
        choice,
        desc = "overlap: spool overlap (default); amplifier: dead zone of the amplifier ahead of the \
         underlapped spool"
    )]
    pub variant: DeadbandVariant,
    /// Amplifier dead zone as a fraction of the full-scale command (-), variant `amplifier`.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "amplifier dead zone, fraction of the full-scale command (variant amplifier)")]
    pub deadzone: f64,
    /// Overlap per edge as a fraction of full spool travel (-).
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "overlap per edge, fraction of travel", uncertain(order = 17, to_range_end))]
    pub overlap: f64,
    /// Zero offset of the spool as a fraction of full travel (-), signed.
    #[serde(default)]
    #[param(unit = "-", range = Within(-0.5, 0.5), desc = "spool zero offset, fraction of travel", uncertain(order = 16, to_range_end))]
    pub zero_offset: f64,
}
