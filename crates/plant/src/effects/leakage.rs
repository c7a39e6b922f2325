//! `internal_leakage` (cross-piston, 003 eq. 1 k_l, 004 C_in) and `external_leakage` (chambers to
//! tank, 003 eq. 1 k_le; equal or per chamber, variant `per_chamber`): laminar leakage
//! Q = k·Δp. One module for both, as they share one section type, [`Leakage`]
//! (`[effects.internal_leakage]`, `[effects.external_leakage]`); the flows enter the chamber
//! balances in crates/plant/src/model.rs.

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

/// Leakage coefficients (m³/(s·Pa)) the chamber balances use (`Plant::configure`,
/// crates/plant/src/model.rs): cross-piston k_in from `internal`, chamber A's and chamber B's
/// to tank from `external` (B's is A's unless variant `per_chamber`); 0 for a section that is
/// absent or switched off.
pub(crate) fn coefficients(
    internal: Option<&Leakage>,
    external: Option<&Leakage>,
) -> (f64, f64, f64) {
    let ext = external.filter(|l| l.enabled);
    (
        internal
            .filter(|l| l.enabled)
            .map_or(0.0, |l| l.coefficient),
        ext.map_or(0.0, |l| l.coefficient),
        ext.map_or(0.0, |l| match l.variant {
            LeakageVariant::Equal => l.coefficient,
            LeakageVariant::PerChamber => l.coefficient_b,
        }),
    )
}
