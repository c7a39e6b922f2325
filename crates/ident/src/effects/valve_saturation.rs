//! `valve_saturation`: spool travel limit, symmetric or per direction (variant `asymmetric`). Model
//! and sources: `ValveSaturation` in crates/plant/src/effects/valve_saturation.rs.
//!
//! Seeds: spool limit 0.9 of the stroke (bounds 0.05…1); the per-direction limits of the
//! `asymmetric` variant at 0.9 of the travel the record's command reaches in that direction
//! ([`Scales::spool_reach`]). Above that reach a limit never clips the recorded command, so
//! the cost does not change with it and the simplex would not move the limit: on the Sjöberg
//! record (commands reach 16 % and 18 % of travel) a seed at 0.9 left the variant at the
//! refit's error.

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{SaturationVariant, ValveSaturation};
use ehactl_plant::{EffectId, PlantParams};

/// The experiment that separates a spool limit from a supply sag.
pub(crate) const SUPPLY_EXPERIMENT: &str = "large steady commands at a low load: a spool limit caps flow at any pressure, a supply sag shows as falling supply pressure at high flow (log p_s)";

/// The catalogue effect `valve_saturation`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Level
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::SupplyPressureDrop).then_some(SUPPLY_EXPERIMENT)
    }

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
        sc: &Scales,
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
            // Inside the reach of the command, unless it stays below the lower bound 0.05
            // (no travel to limit in that direction: the limit is untestable either way).
            let seed_at = |configured: f64, reach: f64| {
                let inside = 0.9 * reach;
                if inside >= 0.05 {
                    configured.min(0.9).min(inside)
                } else {
                    configured.min(0.9)
                }
            };
            let (pos, neg) = (
                seed_at(s0.spool_limit, sc.spool_reach[0]),
                seed_at(s0.spool_limit_negative, sc.spool_reach[1]),
            );
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::EffectFit;
    use std::path::Path;

    /// Residual analysis that names no evidence (the seeds do not read it).
    fn quiet() -> Analysis {
        Analysis {
            nrmse: vec![0.5],
            noise: vec![0.0],
            reversal_ratio: 1.0,
            small_command_ratio: 1.0,
            large_command_ratio: 1.0,
            bias_share: None,
            lag: 0.0,
            tones: Vec::new(),
            mode_frequency: 0.0,
            mode_ratio: 1.0,
            prior: Vec::new(),
        }
    }

    /// On the Sjöberg estimation record (valve opening −1.455 … 1.285 on the config's 8 V
    /// scale, tests/data/measured/sjoberg/README_source.md) both per-direction limits of the
    /// `asymmetric` variant start where they clip the recorded command; a start at 0.9 of the
    /// travel lies on a flat cost and the limit is never fitted.
    #[test]
    fn asymmetric_limits_start_inside_the_recorded_travel() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let nominal =
            ehactl_config::RigConfig::load(&root.join("configs/sjoberg1995_actuator.toml"))
                .unwrap()
                .plant;
        let rec =
            crate::data::load(&root.join("tests/data/measured/sjoberg/estimation.csv")).unwrap();
        let sc = Scales::new(&nominal, &rec);
        // The estimation half's extremes, read off the file independently of the code above.
        let (u_max, u_min) = rec
            .u
            .iter()
            .fold((f64::MIN, f64::MAX), |(a, b), &u| (a.max(u), b.min(u)));
        assert!(
            (sc.spool_reach[0] - u_max / 8.0).abs() < 1e-12,
            "{:?}",
            sc.spool_reach
        );
        assert!(
            (sc.spool_reach[1] + u_min / 8.0).abs() < 1e-12,
            "{:?}",
            sc.spool_reach
        );
        assert!(
            sc.spool_reach.iter().all(|r| (0.1..0.2).contains(r)),
            "{:?}",
            sc.spool_reach
        );
        let first = Effect.params(&nominal, &sc, &quiet()).unwrap();
        let variants = Effect.variants(&nominal, &sc, first);
        let (_, asym) = variants.iter().find(|(n, _)| *n == "asymmetric").unwrap();
        for (fp, reach) in asym.iter().zip(sc.spool_reach) {
            assert!(
                fp.init < reach && fp.init >= 0.05,
                "{} starts at {} with the command reaching {reach}",
                fp.name,
                fp.init
            );
        }
    }

    /// A direction the command does not reach (≤ 0.05/0.9 of travel) keeps the configured
    /// start: no limit there can be told from the record, so none is invented at the bound.
    #[test]
    fn unreached_direction_keeps_the_default_start() {
        let mut nominal = ehactl_config::RigConfig::from_toml_str(include_str!(
            "../../../../configs/diagnose_testrig.toml"
        ))
        .unwrap()
        .plant;
        nominal.effects.valve_saturation = None;
        let sc = Scales {
            force: 1e4,
            flow: 1e-4,
            pressure: 1e7,
            mass: 10.0,
            stiffness: 1e7,
            dt: 1e-3,
            spool_reach: [0.5, 0.0],
        };
        let first = Effect.params(&nominal, &sc, &quiet()).unwrap();
        let variants = Effect.variants(&nominal, &sc, first);
        let (_, asym) = variants.iter().find(|(n, _)| *n == "asymmetric").unwrap();
        assert_eq!(asym[0].init, 0.45);
        assert_eq!(asym[1].init, 0.9);
    }
}
