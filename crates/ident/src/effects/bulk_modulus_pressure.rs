//! `bulk_modulus_pressure`: pressure-dependent bulk modulus β(p) = β₀ + K_b·p capped at `max`, or
//! entrained air (variant `entrained_air`). Model and sources: `BulkModulusPressure` in
//! crates/plant/src/effects/bulk_modulus_pressure.rs.
//!
//! Seeds: slope K_b = 5 (bounds 0…400), cap max(2.2 GPa, 1.6·β₀); air fraction 0.5 % (10⁻⁵…0.1,
//! polytropic index 1.4).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{BulkModulusPressure, BulkVariant};
use ehactl_plant::{EffectId, PlantParams};

/// The catalogue effect `bulk_modulus_pressure`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Mode
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        match other {
            EffectId::LineDynamics | EffectId::FlexibleMount => Some(super::MODE_EXPERIMENT),
            _ => None,
        }
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        an.mode_prior()
    }

    fn params(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        _an: &Analysis,
    ) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let b0 = nominal.fluid.bulk_modulus;
        let cur = ef
            .bulk_modulus_pressure
            .clone()
            .unwrap_or(BulkModulusPressure {
                enabled: true,
                variant: BulkVariant::Linear,
                air_fraction: 0.0,
                polytropic_index: 1.4,
                slope: 0.0,
                max: (2.2e9f64).max(1.6 * b0),
            });
        let init = cur.slope.max(5.0);
        let seed = seeded(nominal, |e| e.bulk_modulus_pressure = Some(cur));
        Some(vec![at(
            "effects.bulk_modulus_pressure.slope",
            (0.0, 400.0, false, init),
            &seed,
        )])
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.bulk_modulus_pressure.as_ref().map(|d| d.variant);
        if cur != Some(BulkVariant::EntrainedAir) {
            out.push(("linear", first));
        }
        if cur.is_none() || cur == Some(BulkVariant::EntrainedAir) {
            let b0 = ef
                .bulk_modulus_pressure
                .clone()
                .unwrap_or(BulkModulusPressure {
                    enabled: true,
                    variant: BulkVariant::EntrainedAir,
                    slope: 0.0,
                    air_fraction: 0.005,
                    polytropic_index: 1.4,
                    max: 2.2e9,
                });
            let init = b0.air_fraction.max(1e-3);
            let seed = seeded(nominal, |e| e.bulk_modulus_pressure = Some(b0));
            out.push((
                "entrained_air",
                vec![FreeParam::at_then(
                    "effects.bulk_modulus_pressure.air_fraction",
                    (1e-5, 0.1, true, init),
                    &seed,
                    |p| {
                        if let Some(b) = p.effects.bulk_modulus_pressure.as_mut() {
                            b.variant = BulkVariant::EntrainedAir;
                        }
                    },
                )],
            ));
        }
        out
    }
}
