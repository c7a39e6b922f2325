//! `supply_pressure_drop`: the supply pressure sags with the valve's flow, p_s → p_s0 − R·Q_s with
//! time constant τ (000), or a flow-limited pressure-compensated pump feeding a volume (variant
//! `pump_limit`; Manring 2005, "Hydraulic Control Systems", §6.5): the config section
//! [`SupplyPressureDrop`] (`[effects.supply_pressure_drop]`), its substep [`SupplyModel`] and
//! its component [`Supply`], the supply stage of the substep ([`SupplyStage`]).

use super::component::{Component, Setup, SupplyStage};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `supply_pressure_drop`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum SupplyVariant {
    /// p_s → p_s0 − R·Q_s with time constant τ (000): accumulator behind a supply resistance.
    #[default]
    Resistance,
    /// Pressure-compensated pump with a flow limit feeding a supply volume V:
    /// (V/β₀)·ṗ_s = Q_p − Q_s with Q_p = Q_max·clamp((p_s0 − p_s)/Δp_c, 0, 1): the compensator
    /// destrokes linearly over its regulation band Δp_c below the setting p_s0, and the supply
    /// collapses when the valve draws more than Q_max (Manring, "Hydraulic Control Systems"
    /// 2005, §6.5 pressure-compensated pumps).
    PumpLimit,
}

/// `supply_pressure_drop`: supply sags with flow, p_s → p_s0 − R·Q_s with time constant τ (000),
/// or a flow-limited pressure-compensated pump (variant `pump_limit`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SupplyPressureDrop {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`resistance` or `pump_limit`).
    #[serde(default)]
    #[param(
        choice,
        desc = "resistance: p_s0 − R·Q_s with lag τ (000, default); pump_limit: pressure-compensated \
         pump with flow limit Q_max into a volume"
    )]
    pub variant: SupplyVariant,
    /// Flow resistance R (Pa·s/m³), variant `resistance`.
    #[serde(default)]
    #[param(unit = "Pa·s/m³", range = NonNegative, desc = "supply flow resistance R")]
    pub resistance: f64,
    /// Time constant τ of the supply (accumulator / pump) (s), variant `resistance`.
    #[serde(default)]
    #[param(unit = "s", range = Positive, desc = "supply time constant τ")]
    pub time_constant: f64,
    /// Pump flow limit Q_max (m³/s), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "m³/s", range = Positive, desc = "pump flow limit Q_max (variant pump_limit)")]
    pub max_flow: f64,
    /// Compensator regulation band Δp_c (Pa), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "compensator regulation band Δp_c below the setting (variant pump_limit)")]
    pub regulation_band: f64,
    /// Oil volume between pump and valve V (m³), variant `pump_limit`.
    #[serde(default)]
    #[param(unit = "m³", range = Positive, desc = "oil volume between pump and valve (variant pump_limit)")]
    pub volume: f64,
}

impl SupplyPressureDrop {
    /// Cross-field check of the variant: each variant's own parameters are given and > 0.
    pub(crate) fn validate_variant(&self) -> Result<(), ConfigError> {
        match self.variant {
            SupplyVariant::Resistance if !(self.time_constant > 0.0) => {
                return Err(ConfigError::new(
                    "effects.supply_pressure_drop.time_constant",
                    "must be > 0 s for variant = \"resistance\"",
                ))
            }
            SupplyVariant::PumpLimit
                if !(self.max_flow > 0.0 && self.regulation_band > 0.0 && self.volume > 0.0) =>
            {
                return Err(ConfigError::new(
                    "effects.supply_pressure_drop",
                    format!(
                        "variant = \"pump_limit\" needs max_flow > 0 m³/s, regulation_band > 0 Pa and volume > 0 m³; got {} m³/s, {} Pa, {} m³",
                        self.max_flow, self.regulation_band, self.volume
                    ),
                ))
            }
            _ => {}
        }
        Ok(())
    }
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
    /// [`SupplyVariant::PumpLimit`]).
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
    pub fn new(s: &SupplyPressureDrop, ps0: f64, beta0: f64) -> Self {
        match s.variant {
            SupplyVariant::Resistance => SupplyModel::Resistance {
                ps0,
                r: s.resistance,
                tau: s.time_constant,
            },
            SupplyVariant::PumpLimit => SupplyModel::PumpLimit {
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

/// The component of `supply_pressure_drop`: the supply model (absent without the effect) and
/// the constants the plant reads of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Supply {
    /// The substep model, `None` when the section is absent or switched off.
    model: Option<SupplyModel>,
    /// Equivalent droop (Pa·s/m³), 0 without the effect.
    droop: f64,
    /// Time constant τ (s) of variant `resistance`, floored at 1 ns; 1 s without the effect.
    tau: f64,
}

impl Component for Supply {
    type Section = SupplyPressureDrop;

    /// Each variant's own parameters are given and admissible.
    fn validate(s: &SupplyPressureDrop) -> Result<(), ConfigError> {
        s.validate_variant()
    }

    /// With the nominal supply pressure p_s0 and the fluid's β₀ of `setup`.
    fn configure(s: Option<&SupplyPressureDrop>, setup: &Setup) -> Self {
        let (ps0, beta0) = (setup.supply_pressure, setup.bulk_modulus);
        let sdrop = s.filter(|s| s.enabled);
        Supply {
            model: sdrop.map(|s| SupplyModel::new(s, ps0, beta0)),
            droop: sdrop.map_or(0.0, |s| SupplyModel::new(s, ps0, beta0).droop()),
            tau: sdrop.map_or(1.0, |s| s.time_constant.max(1e-9)),
        }
    }

    /// No state of its own: p_s is set with the plant state.
    fn reset(&mut self) {}
}

impl SupplyStage for Supply {
    fn droop(&self) -> f64 {
        self.droop
    }

    fn time_constant(&self) -> f64 {
        self.tau
    }

    fn is_linear(&self) -> bool {
        !matches!(self.model, Some(SupplyModel::PumpLimit { .. }))
    }

    fn is_active(&self) -> bool {
        self.model.is_some()
    }

    /// [`SupplyModel::advance`].
    #[inline]
    fn advance(&self, ps: f64, qs: f64, pt: f64, h: f64) -> f64 {
        match &self.model {
            Some(sm) => sm.advance(ps, qs, pt, h),
            None => ps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETUP: Setup = Setup::TEST;

    fn section(variant: SupplyVariant) -> SupplyPressureDrop {
        SupplyPressureDrop {
            enabled: true,
            variant,
            resistance: 2e10,
            time_constant: 0.02,
            max_flow: 1e-4,
            regulation_band: 1e6,
            volume: 1e-3,
        }
    }

    /// Without the effect (absent or switched off) p_s is no state: it stays, with no droop,
    /// and `linear_exact` may run.
    #[test]
    fn without_the_effect_the_supply_pressure_stays() {
        let mut off = section(SupplyVariant::Resistance);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let st = Supply::configure(s, &SETUP);
            assert!(!st.is_active() && st.is_linear());
            assert_eq!((st.droop(), st.time_constant()), (0.0, 1.0));
            assert_eq!(st.advance(19e6, 1e-4, 0.0, 1e-4), 19e6);
        }
    }

    /// Variant `resistance`: p_s relaxes towards p_s0 − R·Q_s with τ, exactly over a step.
    #[test]
    fn resistance_relaxes_to_the_drooped_pressure() {
        let st = Supply::configure(Some(&section(SupplyVariant::Resistance)), &SETUP);
        assert!(st.is_active() && st.is_linear());
        assert_eq!((st.droop(), st.time_constant()), (2e10, 0.02));
        // Q_s = 1e-4 m³/s: target 20 MPa − 2 MPa = 18 MPa; one τ from 20 MPa.
        let p = st.advance(20e6, 1e-4, 0.0, 0.02);
        let want = 18e6 + 2e6 * (-1.0f64).exp();
        assert!((p - want).abs() < 1e-6, "{p} vs {want}");
    }

    /// Variant `pump_limit`: nonlinear (no `linear_exact`); the droop is Δp_c/Q_max; a
    /// demand above Q_max empties the volume at (q_s − Q_max)/C below the band.
    #[test]
    fn pump_limit_is_nonlinear_and_sags_beyond_its_flow() {
        let st = Supply::configure(Some(&section(SupplyVariant::PumpLimit)), &SETUP);
        assert!(st.is_active() && !st.is_linear());
        assert!((st.droop() - 1e6 / 1e-4).abs() < 1e-3);
        let (ps, h) = (15e6, 1e-4);
        let p = st.advance(ps, 3e-4, 0.0, h);
        let want = ps + h * (1e-4 - 3e-4) / (1e-3 / 1.5e9);
        assert!((p - want).abs() < 1e-6, "{p} vs {want}");
    }

    /// The component's check is the variant's: `pump_limit` without its volume is refused.
    #[test]
    fn validate_refuses_a_pump_without_volume() {
        let mut s = section(SupplyVariant::PumpLimit);
        assert!(Supply::validate(&s).is_ok());
        s.volume = 0.0;
        let e = Supply::validate(&s).unwrap_err();
        assert!(
            e.to_string().contains("effects.supply_pressure_drop"),
            "{e}"
        );
    }
}
