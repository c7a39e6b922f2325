//! `valve_saturation`: spool travel limit, symmetric or asymmetric (002 fig. 6: 87 % on one
//! side), and/or an edge flow limit: the config section [`ValveSaturation`]
//! (`[effects.valve_saturation]`) and its component [`Saturation`], the limit stage
//! ([`LimitStage`]) of the valve's edge law (`EdgeLaw` in crates/plant/src/valve.rs).

use super::component::{Component, LimitStage, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
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

/// The component of `valve_saturation`: the spool travel the metering edges can see, as
/// fractions of full travel (-), and the flow through any one edge (m³/s). The limits are
/// infinite without the effect (and the flow limit with `max_flow = 0`). Stateless; the
/// plant holds it among its components and the valve's edge law (`EdgeLaw` in
/// crates/plant/src/valve.rs) takes it by reference and calls its [`LimitStage`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Saturation {
    /// Limit of positive travel (fraction), `spool_limit`.
    positive: f64,
    /// Limit of negative travel (fraction): `spool_limit_negative` for variant
    /// `asymmetric`, else `spool_limit`.
    negative: f64,
    /// Edge flow limit (m³/s).
    max_flow: f64,
}

impl Saturation {
    /// The constants of a section (`None`, or `enabled = false`: no limits); what
    /// [`Component::configure`] derives, for the edge law's users outside the plant.
    pub fn new(section: Option<&ValveSaturation>) -> Self {
        let sat = section.filter(|s| s.enabled);
        Saturation {
            positive: sat.map_or(f64::INFINITY, |s| s.spool_limit),
            negative: sat.map_or(f64::INFINITY, |s| match s.variant {
                SaturationVariant::Symmetric => s.spool_limit,
                SaturationVariant::Asymmetric => s.spool_limit_negative,
            }),
            max_flow: sat
                .map(|s| s.max_flow)
                .filter(|m| *m > 0.0)
                .unwrap_or(f64::INFINITY),
        }
    }
}

impl Component for Saturation {
    type Section = ValveSaturation;

    /// Each field's range is the registry's (limits in [0.01, 1], flow ≥ 0); variant
    /// `symmetric` ignores `spool_limit_negative`: nothing to check across fields.
    fn validate(_s: &ValveSaturation) -> Result<(), ConfigError> {
        Ok(())
    }

    /// [`Saturation::new`].
    fn configure(s: Option<&ValveSaturation>, _setup: &Setup) -> Self {
        Saturation::new(s)
    }

    /// No state.
    fn reset(&mut self) {}
}

impl LimitStage for Saturation {
    /// `travel` clamped to [−negative limit, positive limit].
    #[inline]
    fn clip_travel(&self, travel: f64) -> f64 {
        travel.clamp(-self.negative, self.positive)
    }

    /// (sign(q)·Q_max, 0) where |q| > Q_max, else (q, dq).
    #[inline]
    fn clip_flow(&self, q: f64, dq: f64) -> (f64, f64) {
        if q.abs() > self.max_flow {
            (self.max_flow.copysign(q), 0.0)
        } else {
            (q, dq)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(variant: SaturationVariant, max_flow: f64) -> ValveSaturation {
        ValveSaturation {
            enabled: true,
            variant,
            spool_limit_negative: 0.8,
            spool_limit: 0.5,
            max_flow,
        }
    }

    #[test]
    fn absent_switched_off_or_zero_flow_limits_nothing() {
        let mut off = section(SaturationVariant::Asymmetric, 1e-4);
        off.enabled = false;
        for s in [
            Saturation::configure(None, &Setup::TEST),
            Saturation::configure(Some(&off), &Setup::TEST),
        ] {
            for x in [-1.0, -0.0, 0.0, 0.9, 1.0] {
                assert_eq!(s.clip_travel(x).to_bits(), x.to_bits());
            }
            assert_eq!(s.clip_flow(-1.0, 2.0), (-1.0, 2.0));
        }
        let unlimited = Saturation::configure(
            Some(&section(SaturationVariant::Symmetric, 0.0)),
            &Setup::TEST,
        );
        assert_eq!(unlimited.clip_flow(1e3, 2.0), (1e3, 2.0));
    }

    #[test]
    fn each_variant_limits_its_travel_and_the_flow() {
        let s = Saturation::configure(
            Some(&section(SaturationVariant::Symmetric, 1e-4)),
            &Setup::TEST,
        );
        assert_eq!((s.clip_travel(0.9), s.clip_travel(-0.9)), (0.5, -0.5));
        assert_eq!(s.clip_travel(0.3), 0.3);
        let a = Saturation::configure(
            Some(&section(SaturationVariant::Asymmetric, 1e-4)),
            &Setup::TEST,
        );
        assert_eq!((a.clip_travel(0.9), a.clip_travel(-0.9)), (0.5, -0.8));
        // Beyond Q_max the flow is held, its slope 0; below it both pass.
        assert_eq!(a.clip_flow(3e-4, 1e-11), (1e-4, 0.0));
        assert_eq!(a.clip_flow(-3e-4, 1e-11), (-1e-4, 0.0));
        assert_eq!(a.clip_flow(5e-5, 1e-11), (5e-5, 1e-11));
    }
}
