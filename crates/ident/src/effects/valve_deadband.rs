//! `valve_deadband`: spool overlap (dead zone) and zero offset, or an amplifier dead zone ahead of
//! an underlapped spool (variant `amplifier`). Model and sources: `ValveDeadband` in
//! crates/plant/src/effects/valve_deadband.rs.
//!
//! Seeds: overlap / dead zone 2 % of the spool stroke (bounds 0…30 %), zero offset 0 (±5 %).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{DeadbandVariant, ValveDeadband};
use ehactl_plant::{EffectId, PlantParams};

/// The catalogue effect `valve_deadband`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::SmallCommand
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::Friction).then_some(super::friction::DEADBAND_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        let small_command_ratio = an.small_command_ratio;
        (
            small_command_ratio,
            format!("residual RMS where |u| < 5 % of its maximum is {small_command_ratio:.2}× the overall RMS"),
        )
    }

    fn params(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        _an: &Analysis,
    ) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let d0 = ef.valve_deadband.clone().unwrap_or(ValveDeadband {
            enabled: true,
            variant: DeadbandVariant::Overlap,
            deadzone: 0.0,
            overlap: 0.0,
            zero_offset: 0.0,
        });
        let (overlap, zero_offset) = (d0.overlap.max(0.02), d0.zero_offset);
        let seed = seeded(nominal, |e| e.valve_deadband = Some(d0));
        Some(vec![
            at(
                "effects.valve_deadband.overlap",
                (0.0, 0.3, false, overlap),
                &seed,
            ),
            at(
                "effects.valve_deadband.zero_offset",
                (-0.05, 0.05, false, zero_offset),
                &seed,
            ),
        ])
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.valve_deadband.as_ref().map(|d| d.variant);
        if cur != Some(DeadbandVariant::Amplifier) {
            out.push(("overlap", first));
        }
        if cur.is_none() || cur == Some(DeadbandVariant::Amplifier) {
            let d0 = ef.valve_deadband.clone().unwrap_or(ValveDeadband {
                enabled: true,
                variant: DeadbandVariant::Amplifier,
                deadzone: 0.0,
                overlap: 0.0,
                zero_offset: 0.0,
            });
            let (dz, zo) = (d0.deadzone.max(0.02), d0.zero_offset);
            let seed = seeded(nominal, |e| e.valve_deadband = Some(d0));
            let variant = |p: &mut PlantParams| {
                if let Some(d) = p.effects.valve_deadband.as_mut() {
                    d.variant = DeadbandVariant::Amplifier;
                }
            };
            out.push((
                "amplifier",
                vec![
                    // The amplifier's dead zone sits ahead of an underlapped spool.
                    FreeParam::at_then(
                        "effects.valve_deadband.deadzone",
                        (0.0, 0.3, false, dz),
                        &seed,
                        move |p| {
                            variant(p);
                            if let Some(d) = p.effects.valve_deadband.as_mut() {
                                d.overlap = 0.0;
                            }
                        },
                    ),
                    FreeParam::at_then(
                        "effects.valve_deadband.zero_offset",
                        (-0.05, 0.05, false, zo),
                        &seed,
                        variant,
                    ),
                ],
            ));
        }
        out
    }
}
