//! `internal_leakage` (cross-piston, 003 eq. 1 k_l, 004 C_in) and `external_leakage` (chambers to
//! tank, 003 eq. 1 k_le; equal or per chamber, variant `per_chamber`): laminar leakage
//! Q = k·Δp. One module for both, as they share one section type, [`Leakage`]
//! (`[effects.internal_leakage]`, `[effects.external_leakage]`); one component each,
//! [`CrossPiston`] and [`ToTank`], the flow stages ([`FlowStage`]) whose flows enter the
//! chamber balances of the substep (crates/plant/src/model.rs).

use super::component::{Component, FlowStage, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of a leakage.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LeakageVariant {
    /// One coefficient: across the piston (`internal_leakage`) or from both chambers to tank
    /// with the same coefficient (`external_leakage`).
    #[default]
    Equal,
    /// `external_leakage` only: chamber A leaks with `coefficient`, chamber B with
    /// `coefficient_b` (rod seal vs. a worn port or fitting; one chamber when the other is 0).
    PerChamber,
}

/// `internal_leakage` / `external_leakage`: laminar leakage (003 eq. 1 k_l, k_le; 004 C_in).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`equal` or, external leakage only, `per_chamber`).
    #[serde(default)]
    #[param(
        choice,
        desc = "equal: both chambers leak to tank with `coefficient` (default); per_chamber: A with \
         `coefficient`, B with `coefficient_b`"
    )]
    pub variant: LeakageVariant,
    /// Leakage coefficient (m³/(s·Pa)); chamber A's for `per_chamber`.
    #[param(unit = "m³/(s·Pa)", range = NonNegative, desc = "leakage to tank k_le")]
    pub coefficient: f64,
    /// Chamber B's leakage coefficient to tank (m³/(s·Pa)), variant `per_chamber`.
    #[serde(default)]
    #[param(unit = "m³/(s·Pa)", range = NonNegative, desc = "chamber B leakage to tank (variant per_chamber)")]
    pub coefficient_b: f64,
}

impl Leakage {
    /// Cross-field check of an `internal_leakage` section: cross-piston leakage has one coefficient.
    pub(crate) fn validate_internal_variant(&self) -> Result<(), ConfigError> {
        if self.variant != LeakageVariant::Equal {
            return Err(ConfigError::new(
                "effects.internal_leakage.variant",
                "cross-piston leakage has one coefficient; expected \"equal\" (per-chamber leakage to tank is external_leakage.variant = \"per_chamber\")",
            ));
        }
        Ok(())
    }
}

/// The component of `internal_leakage`: the cross-piston flow k_in·(p_A − p_B) out of A into B.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossPiston {
    /// k_in (m³/(s·Pa)), 0 without the effect.
    k: f64,
}

impl Component for CrossPiston {
    type Section = Leakage;

    /// Cross-piston leakage has one coefficient (variant `equal`).
    fn validate(s: &Leakage) -> Result<(), ConfigError> {
        s.validate_internal_variant()
    }

    /// k_in = `coefficient`; 0 for a section that is absent or switched off.
    fn configure(s: Option<&Leakage>, _setup: &Setup) -> Self {
        CrossPiston {
            k: s.filter(|l| l.enabled).map_or(0.0, |l| l.coefficient),
        }
    }

    /// No state.
    fn reset(&mut self) {}
}

impl FlowStage for CrossPiston {
    /// (q, −q) with q = k_in·(p_A − p_B) (003 eq. 1 k_l, 004 C_in).
    #[inline]
    fn flows(&self, p_a: f64, p_b: f64) -> (f64, f64) {
        let q = self.k * (p_a - p_b);
        (q, -q)
    }

    /// (k_in, k_in).
    #[inline]
    fn conductances(&self) -> (f64, f64) {
        (self.k, self.k)
    }
}

/// The component of `external_leakage`: each chamber's flow to tank, k_A·p_A and k_B·p_B
/// (003 eq. 1 k_le), with k_B = k_A unless variant `per_chamber`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToTank {
    /// k_A (m³/(s·Pa)), 0 without the effect.
    k_a: f64,
    /// k_B (m³/(s·Pa)), 0 without the effect.
    k_b: f64,
}

impl Component for ToTank {
    type Section = Leakage;

    /// Either variant applies to leakage to tank: nothing to check across fields.
    fn validate(_s: &Leakage) -> Result<(), ConfigError> {
        Ok(())
    }

    /// k_A = `coefficient`, k_B = `coefficient_b` for variant `per_chamber`, else k_A; 0 for
    /// a section that is absent or switched off.
    fn configure(s: Option<&Leakage>, _setup: &Setup) -> Self {
        let ext = s.filter(|l| l.enabled);
        ToTank {
            k_a: ext.map_or(0.0, |l| l.coefficient),
            k_b: ext.map_or(0.0, |l| match l.variant {
                LeakageVariant::Equal => l.coefficient,
                LeakageVariant::PerChamber => l.coefficient_b,
            }),
        }
    }

    /// No state.
    fn reset(&mut self) {}
}

impl FlowStage for ToTank {
    /// (k_A·p_A, k_B·p_B).
    #[inline]
    fn flows(&self, p_a: f64, p_b: f64) -> (f64, f64) {
        (self.k_a * p_a, self.k_b * p_b)
    }

    /// (k_A, k_B).
    #[inline]
    fn conductances(&self) -> (f64, f64) {
        (self.k_a, self.k_b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETUP: Setup = Setup::TEST;

    /// `got` equals `want` to rounding (1e-12 relative), per component.
    fn close(got: (f64, f64), want: (f64, f64)) {
        for (g, w) in [(got.0, want.0), (got.1, want.1)] {
            assert!((g - w).abs() <= 1e-12 * w.abs(), "{got:?} vs {want:?}");
        }
    }

    fn section(variant: LeakageVariant, coefficient: f64, coefficient_b: f64) -> Leakage {
        Leakage {
            enabled: true,
            variant,
            coefficient,
            coefficient_b,
        }
    }

    /// Without the effect (absent or switched off) no flow and no conductance.
    #[test]
    fn without_the_effect_nothing_leaks() {
        let mut off = section(LeakageVariant::Equal, 1e-12, 0.0);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let x = CrossPiston::configure(s, &SETUP);
            let t = ToTank::configure(s, &SETUP);
            assert_eq!(x.flows(5e6, 1e6), (0.0, 0.0));
            assert_eq!(x.conductances(), (0.0, 0.0));
            assert_eq!(t.flows(5e6, 1e6), (0.0, 0.0));
            assert_eq!(t.conductances(), (0.0, 0.0));
        }
    }

    /// Cross-piston: k·(p_A − p_B) leaves A and enters B; both chambers see k.
    #[test]
    fn cross_piston_flow_goes_from_a_to_b() {
        let x = CrossPiston::configure(Some(&section(LeakageVariant::Equal, 2e-12, 0.0)), &SETUP);
        close(x.flows(5e6, 1e6), (8e-6, -8e-6));
        assert_eq!(x.conductances(), (2e-12, 2e-12));
    }

    /// To tank: one coefficient for `equal`, A's and B's own for `per_chamber`.
    #[test]
    fn to_tank_per_variant() {
        let eq = ToTank::configure(Some(&section(LeakageVariant::Equal, 2e-12, 7e-12)), &SETUP);
        close(eq.flows(5e6, 1e6), (1e-5, 2e-6));
        assert_eq!(eq.conductances(), (2e-12, 2e-12));
        let pc = ToTank::configure(
            Some(&section(LeakageVariant::PerChamber, 2e-12, 7e-12)),
            &SETUP,
        );
        close(pc.flows(5e6, 1e6), (1e-5, 7e-6));
        assert_eq!(pc.conductances(), (2e-12, 7e-12));
    }

    /// Cross-piston leakage refuses `per_chamber`, naming the parameter; leakage to tank
    /// takes both variants.
    #[test]
    fn validate_refuses_per_chamber_across_the_piston() {
        let pc = section(LeakageVariant::PerChamber, 2e-12, 7e-12);
        let e = CrossPiston::validate(&pc).unwrap_err();
        assert!(
            e.to_string().contains("effects.internal_leakage.variant"),
            "{e}"
        );
        assert!(CrossPiston::validate(&section(LeakageVariant::Equal, 2e-12, 0.0)).is_ok());
        assert!(ToTank::validate(&pc).is_ok());
    }
}
