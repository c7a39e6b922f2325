//! `valve_saturation`: spool travel limit, symmetric or asymmetric (002 fig. 6: 87 % on one
//! side), and/or an edge flow limit: the config section [`ValveSaturation`]
//! (`[effects.valve_saturation]`). The limits act in `EdgeLaw` (crates/plant/src/valve.rs)
//! with the valve's other edge parameters.

use super::switch::yes;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `valve_saturation`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum SaturationVariant {
    /// The same travel limit in both directions.
    #[default]
    Symmetric,
    /// Different limits for positive (`spool_limit`) and negative (`spool_limit_negative`)
    /// spool travel: asymmetric amplifier clipping or end stops of the spool (002 fig. 6
    /// shows an 87 % limit on one side).
    Asymmetric,
}

/// `valve_saturation`: spool travel limit and/or edge flow limit (002: 87 %).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveSaturation {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`symmetric` or `asymmetric`).
    #[serde(default)]
    #[param(
        choice,
        desc = "symmetric: one spool travel limit (default); asymmetric: spool_limit for + and \
         spool_limit_negative for − travel"
    )]
    pub variant: SaturationVariant,
    /// Limit of negative spool travel as a fraction of full travel (-), variant `asymmetric`.
    #[serde(default = "ValveSaturation::one")]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "negative spool travel limit, fraction (variant asymmetric)")]
    pub spool_limit_negative: f64,
    /// Maximum spool opening as a fraction of full travel (-), 0 < limit ≤ 1.
    #[serde(default = "ValveSaturation::one")]
    #[param(unit = "-", range = Within(0.01, 1.0), desc = "spool travel limit, fraction")]
    pub spool_limit: f64,
    /// Maximum flow through any one edge (m³/s); 0 = unlimited.
    #[serde(default)]
    #[param(unit = "m³/s", range = NonNegative, desc = "edge flow limit (0 = none)")]
    pub max_flow: f64,
}

impl ValveSaturation {
    fn one() -> f64 {
        1.0
    }
}
