//! `bulk_modulus_pressure`: pressure-dependent bulk modulus β(p) = β₀ + K_b·p, capped at `max`
//! (002 eq. 35–36), or oil with entrained air compressed polytropically (variant
//! `entrained_air`; Yu, Chen & Lu 1994, the "Yu" model of Gholizadeh, Burton & Schoenau 2011,
//! Int. J. Fluid Power 12(3), eq. 20): the config section [`BulkModulusPressure`]
//! (`[effects.bulk_modulus_pressure]`) and the entrained-air law
//! [`entrained_air_bulk_modulus`], and its component [`BulkModulus`], the chambers' bulk
//! modulus stage ([`BulkStage`]).

use super::component::{BulkStage, Component, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `bulk_modulus_pressure`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum BulkVariant {
    /// β(p) = β₀ + K_b·p, capped at `max` (002 eq. 35).
    #[default]
    Linear,
    /// Entrained air compressed polytropically (Yu, Chen & Lu 1994; the "Yu" model of
    /// Gholizadeh, Burton & Schoenau 2011, Int. J. Fluid Power 12(3)): with absolute pressure
    /// P = p + 101325 Pa, air fraction at atmosphere α₀ and polytropic index n,
    /// β(p) = [(1−α₀) + α₀(P₀/P)^(1/n)] / [(1−α₀)/β₀ + α₀(P₀/P)^(1/n)/(n·P)].
    EntrainedAir,
}

/// `bulk_modulus_pressure`: β(p) = β₀ + K_b·p, capped at `max` (002 eq. 35), or entrained air
/// (variant `entrained_air`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BulkModulusPressure {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`linear` or `entrained_air`).
    #[serde(default)]
    #[param(
        choice,
        desc = "linear: β₀ + K_b·p (002 eq. 35, default); entrained_air: Yu 1994 / Gholizadeh 2011 \
         air–oil mixture"
    )]
    pub variant: BulkVariant,
    /// Pressure slope K_b (-): dβ/dp, variant `linear`.
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "dβ/dp K_b (002 eq. 35)")]
    pub slope: f64,
    /// Volume fraction of undissolved air at atmospheric pressure α₀ (-), variant
    /// `entrained_air`; Gholizadeh 2011: 0.5–5 % typical.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.5), desc = "undissolved air volume fraction at atmospheric pressure α₀ (variant entrained_air)")]
    pub air_fraction: f64,
    /// Polytropic index n of the air (-), variant `entrained_air`: 1 isothermal, 1.4 adiabatic.
    #[serde(default = "BulkModulusPressure::default_n")]
    #[param(unit = "-", range = Within(1.0, 1.4), desc = "polytropic index of the air n: 1 isothermal … 1.4 adiabatic (variant entrained_air)")]
    pub polytropic_index: f64,
    /// Upper bound on β (Pa).
    #[serde(default = "BulkModulusPressure::default_max")]
    #[param(unit = "Pa", range = Positive, desc = "upper bound on β")]
    pub max: f64,
}

impl BulkModulusPressure {
    fn default_max() -> f64 {
        2.2e9
    }
    fn default_n() -> f64 {
        1.4
    }
}

impl BulkModulusPressure {
    /// Cross-field check of the variant: `entrained_air` needs an air fraction > 0.
    pub(crate) fn validate_variant(&self) -> Result<(), ConfigError> {
        if self.variant == BulkVariant::EntrainedAir && !(self.air_fraction > 0.0) {
            return Err(ConfigError::new(
                "effects.bulk_modulus_pressure.air_fraction",
                "must be > 0 (volume fraction of air at atmospheric pressure, -) for variant = \"entrained_air\"",
            ));
        }
        Ok(())
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

/// The component of `bulk_modulus_pressure`: the constants of the chambers' β(p) derived
/// from the section and the fluid's β₀.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BulkModulus {
    /// β₀ (Pa), `fluid.bulk_modulus`.
    beta0: f64,
    /// Slope K_b (-), 0 without the effect.
    slope: f64,
    /// Cap β_max (Pa), at least β₀; β₀ without the effect.
    max: f64,
    /// Entrained air (α₀ (-), n (-)) of variant `entrained_air`.
    air: Option<(f64, f64)>,
}

impl Component for BulkModulus {
    type Section = BulkModulusPressure;

    /// `entrained_air` needs an air fraction > 0.
    fn validate(s: &BulkModulusPressure) -> Result<(), ConfigError> {
        s.validate_variant()
    }

    /// With the fluid's β₀ of `setup`: K_b, β_max = max(`max`, β₀) and, for variant
    /// `entrained_air`, (α₀, n); without the effect (absent or switched off) 0, β₀ and none,
    /// i.e. β = β₀.
    fn configure(s: Option<&BulkModulusPressure>, setup: &Setup) -> Self {
        let beta0 = setup.bulk_modulus;
        let bmp = s.filter(|b| b.enabled);
        BulkModulus {
            beta0,
            slope: bmp.map_or(0.0, |b| b.slope),
            max: bmp.map_or(beta0, |b| b.max.max(beta0)),
            air: bmp
                .filter(|b| b.variant == BulkVariant::EntrainedAir)
                .map(|b| (b.air_fraction, b.polytropic_index)),
        }
    }

    /// No state.
    fn reset(&mut self) {}
}

impl BulkStage for BulkModulus {
    /// With entrained air [`entrained_air_bulk_modulus`], else β₀ + K_b·max(p, 0) capped at
    /// β_max (002 eq. 35); β₀ without the effect (K_b = 0, β_max = β₀).
    #[inline]
    fn bulk_modulus(&self, p: f64) -> f64 {
        if let Some((alpha0, n)) = self.air {
            return entrained_air_bulk_modulus(self.beta0, alpha0, n, p);
        }
        (self.beta0 + self.slope * p.max(0.0)).min(self.max)
    }

    /// β_max.
    fn max(&self) -> f64 {
        self.max
    }

    /// False for variant `entrained_air`.
    fn is_linear(&self) -> bool {
        self.air.is_none()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETUP: Setup = Setup::TEST;

    fn section(variant: BulkVariant) -> BulkModulusPressure {
        BulkModulusPressure {
            enabled: true,
            variant,
            slope: 10.0,
            air_fraction: 0.01,
            polytropic_index: 1.4,
            max: 1.6e9,
        }
    }

    /// Without the effect (absent or switched off) β = β₀ at every pressure.
    #[test]
    fn without_the_effect_beta_is_beta0() {
        let mut off = section(BulkVariant::Linear);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let b = BulkModulus::configure(s, &SETUP);
            assert!(b.is_linear());
            assert_eq!(b.max(), 1.5e9);
            for p in [-1e5, 0.0, 1e7, 1e9] {
                assert_eq!(b.bulk_modulus(p), 1.5e9);
            }
        }
    }

    /// Variant `linear`: β₀ + K_b·p above 0 Pa, β₀ below, capped at `max`.
    #[test]
    fn linear_rises_with_pressure_up_to_the_cap() {
        let b = BulkModulus::configure(Some(&section(BulkVariant::Linear)), &SETUP);
        assert!(b.is_linear());
        assert_eq!(b.max(), 1.6e9);
        assert_eq!(b.bulk_modulus(-1e6), 1.5e9);
        assert_eq!(b.bulk_modulus(5e6), 1.5e9 + 10.0 * 5e6);
        assert_eq!(b.bulk_modulus(5e7), 1.6e9);
        // A cap below β₀ is raised to β₀.
        let mut low = section(BulkVariant::Linear);
        low.max = 1e9;
        assert_eq!(BulkModulus::configure(Some(&low), &SETUP).max(), 1.5e9);
    }

    /// Variant `entrained_air`: the Yu law, not held by `linear_exact`; air softens the oil
    /// most at low pressure.
    #[test]
    fn entrained_air_is_the_yu_law() {
        let b = BulkModulus::configure(Some(&section(BulkVariant::EntrainedAir)), &SETUP);
        assert!(!b.is_linear());
        for p in [0.0, 1e6, 1e7] {
            assert_eq!(
                b.bulk_modulus(p),
                entrained_air_bulk_modulus(1.5e9, 0.01, 1.4, p)
            );
        }
        assert!(b.bulk_modulus(1e5) < b.bulk_modulus(1e7));
        assert!(b.bulk_modulus(1e7) < 1.5e9);
    }

    /// The component's check is the variant's: `entrained_air` without air is refused.
    #[test]
    fn validate_refuses_entrained_air_without_air() {
        let mut s = section(BulkVariant::EntrainedAir);
        assert!(BulkModulus::validate(&s).is_ok());
        s.air_fraction = 0.0;
        let e = BulkModulus::validate(&s).unwrap_err();
        assert!(
            e.to_string()
                .contains("effects.bulk_modulus_pressure.air_fraction"),
            "{e}"
        );
    }
}
