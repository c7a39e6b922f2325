//! `valve_saturation`: spool travel limit, symmetric or per direction (variant `asymmetric`). Model
//! and sources: `ValveSaturation` in crates/plant/src/effects/valve_saturation.rs.
//!
//! Seeds: spool limit 0.9 of the stroke (bounds 0.05…1).

use super::EffectFit;
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use crate::rng::Rng;
use ehactl_plant::params::{SaturationVariant, ValveSaturation};
use ehactl_plant::PlantParams;

/// The catalogue effect `valve_saturation`.
pub struct Effect;

impl EffectFit for Effect {
    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        an.large_command_prior()
    }

    fn params(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        _an: &Analysis,
    ) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let s0 = ef.valve_saturation.clone().unwrap_or(ValveSaturation {
            enabled: true,
            variant: SaturationVariant::Symmetric,
            spool_limit_negative: 1.0,
            spool_limit: 1.0,
            max_flow: 0.0,
        });
        let init = s0.spool_limit.min(0.9);
        let seed = seeded(nominal, |e| e.valve_saturation = Some(s0));
        Some(vec![at(
            "effects.valve_saturation.spool_limit",
            (0.05, 1.0, false, init),
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
        let cur = ef.valve_saturation.as_ref().map(|d| d.variant);
        if cur != Some(SaturationVariant::Asymmetric) {
            out.push(("symmetric", first));
        }
        if cur.is_none() || cur == Some(SaturationVariant::Asymmetric) {
            let s0 = ef.valve_saturation.clone().unwrap_or(ValveSaturation {
                enabled: true,
                variant: SaturationVariant::Asymmetric,
                spool_limit: 1.0,
                spool_limit_negative: 1.0,
                max_flow: 0.0,
            });
            let (pos, neg) = (s0.spool_limit.min(0.9), s0.spool_limit_negative.min(0.9));
            let seed = seeded(nominal, |e| e.valve_saturation = Some(s0));
            let variant = |p: &mut PlantParams| {
                if let Some(s) = p.effects.valve_saturation.as_mut() {
                    s.variant = SaturationVariant::Asymmetric;
                }
            };
            out.push((
                "asymmetric",
                vec![
                    FreeParam::at_then(
                        "effects.valve_saturation.spool_limit",
                        (0.05, 1.0, false, pos),
                        &seed,
                        variant,
                    ),
                    FreeParam::at_then(
                        "effects.valve_saturation.spool_limit_negative",
                        (0.05, 1.0, false, neg),
                        &seed,
                        variant,
                    ),
                ],
            ));
        }
        out
    }

    fn hide(&self, p: &mut PlantParams, rng: &mut Rng) {
        let ef = &mut p.effects;
        ef.valve_saturation = Some(ValveSaturation {
            enabled: true,
            variant: Default::default(),
            spool_limit_negative: 1.0,
            spool_limit: rng.range(0.45, 0.7),
            max_flow: 0.0,
        });
    }
}
