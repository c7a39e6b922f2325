//! `bulk_modulus_pressure`: pressure-dependent bulk modulus β(p) = β₀ + K_b·p, capped at `max`
//! (002 eq. 35–36), or oil with entrained air compressed polytropically (variant
//! `entrained_air`; Yu, Chen & Lu 1994, the "Yu" model of Gholizadeh, Burton & Schoenau 2011,
//! Int. J. Fluid Power 12(3), eq. 20): the config section [`BulkModulusPressure`]
//! (`[effects.bulk_modulus_pressure]`) and the entrained-air law
//! [`entrained_air_bulk_modulus`].

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

/// β(p) (Pa) at gauge pressure `p` (Pa) from the constants of [`chamber_constants`]: with
/// `air` (α₀, n) the entrained-air law ([`entrained_air_bulk_modulus`]), else
/// β₀ + K_b·max(p, 0) capped at β_max (002 eq. 35); without the effect (K_b = 0, β_max = β₀)
/// β₀.
#[inline]
pub(crate) fn bulk_modulus(
    beta0: f64,
    slope: f64,
    max: f64,
    air: Option<(f64, f64)>,
    p: f64,
) -> f64 {
    if let Some((alpha0, n)) = air {
        return entrained_air_bulk_modulus(beta0, alpha0, n, p);
    }
    (beta0 + slope * p.max(0.0)).min(max)
}

/// What `Plant::configure` (crates/plant/src/model.rs) derives from the section `s` (used when
/// present and enabled) for the chambers' β(p), given the fluid's β₀ (Pa): the slope K_b (-),
/// the cap β_max (Pa) and, for variant `entrained_air`, the air (α₀ (-), n (-)). Without the
/// effect: 0, β₀ and none, i.e. β = β₀.
pub(crate) fn chamber_constants(
    s: Option<&BulkModulusPressure>,
    beta0: f64,
) -> (f64, f64, Option<(f64, f64)>) {
    let bmp = s.filter(|b| b.enabled);
    (
        bmp.map_or(0.0, |b| b.slope),
        bmp.map_or(beta0, |b| b.max.max(beta0)),
        bmp.filter(|b| b.variant == BulkVariant::EntrainedAir)
            .map(|b| (b.air_fraction, b.polytropic_index)),
    )
}
