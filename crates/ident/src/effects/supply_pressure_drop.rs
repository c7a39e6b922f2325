//! `supply_pressure_drop`: supply pressure sagging with flow, p_s → p_s0 − R·Q_s with time constant
//! τ, or a flow-limited pressure-compensated pump (variant `pump_limit`). Model and sources:
//! `SupplyPressureDrop` in crates/plant/src/effects/supply_pressure_drop.rs.
//!
//! Seeds: R = 5 % of the rig's p_s/Q (10⁻³…2×), τ = 20 ms (1 ms…1 s); pump flow = the edge flow Q
//! (0.2…4×), regulation band 5 % of p_s, accumulator volume 0.5 l.

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{SupplyPressureDrop, SupplyVariant};
use ehactl_plant::{EffectId, PlantParams};

/// The catalogue effect `supply_pressure_drop`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Level
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::ValveSaturation).then_some(super::valve_saturation::SUPPLY_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        an.large_command_prior()
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, _an: &Analysis) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let r_s = sc.pressure / sc.flow;
        let cur = ef
            .supply_pressure_drop
            .clone()
            .unwrap_or(SupplyPressureDrop {
                enabled: true,
                variant: SupplyVariant::Resistance,
                resistance: 0.05 * r_s,
                time_constant: 0.02,
                max_flow: 0.0,
                regulation_band: 0.0,
                volume: 0.0,
            });
        let (r0, t0) = (cur.resistance, cur.time_constant);
        let seed = seeded(nominal, |e| e.supply_pressure_drop = Some(cur));
        Some(vec![
            at(
                "effects.supply_pressure_drop.resistance",
                (1e-3 * r_s, 2.0 * r_s, true, r0),
                &seed,
            ),
            at(
                "effects.supply_pressure_drop.time_constant",
                (1e-3, 1.0, true, t0),
                &seed,
            ),
        ])
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.supply_pressure_drop.as_ref().map(|d| d.variant);
        if cur != Some(SupplyVariant::PumpLimit) {
            out.push(("resistance", first));
        }
        if cur.is_none() || cur == Some(SupplyVariant::PumpLimit) {
            let s0 = ef
                .supply_pressure_drop
                .clone()
                .unwrap_or(SupplyPressureDrop {
                    enabled: true,
                    variant: SupplyVariant::PumpLimit,
                    resistance: 0.0,
                    time_constant: 0.0,
                    max_flow: sc.flow,
                    regulation_band: 0.05 * sc.pressure,
                    volume: 5e-4,
                });
            let (q0, band0, v0) = (s0.max_flow, s0.regulation_band, s0.volume);
            let seed = seeded(nominal, |e| e.supply_pressure_drop = Some(s0));
            let variant = |p: &mut PlantParams| {
                if let Some(s) = p.effects.supply_pressure_drop.as_mut() {
                    s.variant = SupplyVariant::PumpLimit;
                }
            };
            out.push((
                "pump_limit",
                vec![
                    FreeParam::at_then(
                        "effects.supply_pressure_drop.max_flow",
                        (0.2 * sc.flow, 4.0 * sc.flow, true, q0),
                        &seed,
                        variant,
                    ),
                    FreeParam::at_then(
                        "effects.supply_pressure_drop.regulation_band",
                        (0.005 * sc.pressure, 0.5 * sc.pressure, true, band0),
                        &seed,
                        variant,
                    ),
                    FreeParam::at_then(
                        "effects.supply_pressure_drop.volume",
                        (2e-5, 1e-2, true, v0),
                        &seed,
                        variant,
                    ),
                ],
            ));
        }
        out
    }
}
