//! `valve_dynamics`: spool dynamics, first order (time constant) or second order (natural frequency
//! ω_v, damping ratio ζ_v). Model and sources: `ValveDynamics` in crates/plant/src/effects/valve_dynamics.rs.
//!
//! Seeds: a configured first-order valve refits its time constant (0.1 ms…0.3 s); otherwise second
//! order at ω_v = 2π·min(0.1/Δt, 200 Hz) (bounds 2π·1 Hz…2π·min(0.5/Δt, 3 kHz)), ζ_v = 0.7 (0.2…2).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::ValveDynamics;
use ehactl_plant::{EffectId, PlantParams};

/// The experiment that separates spool dynamics from a transport delay.
pub(crate) const DELAY_EXPERIMENT: &str = "a sine sweep of the valve command to the spool bandwidth: a delay adds phase linearly in frequency at constant gain, spool dynamics also lower the gain";

/// The catalogue effect `valve_dynamics`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Other
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::TimeDelay).then_some(DELAY_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, dt: f64) -> (f64, String) {
        an.lag_prior(dt)
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, _an: &Analysis) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        Some(match ef.valve_dynamics.clone() {
            Some(d) if d.order == 1 => {
                let init = d.time_constant;
                let seed = seeded(nominal, |e| e.valve_dynamics = Some(d));
                vec![at(
                    "effects.valve_dynamics.time_constant",
                    (1e-4, 0.3, true, init),
                    &seed,
                )]
            }
            other => {
                let d0 = other.unwrap_or(ValveDynamics {
                    enabled: true,
                    order: 2,
                    time_constant: 0.0,
                    natural_frequency: 0.0,
                    damping_ratio: 0.7,
                });
                let (w0, z0) = if d0.natural_frequency > 0.0 {
                    (d0.natural_frequency, d0.damping_ratio)
                } else {
                    (std::f64::consts::TAU * (0.1 / sc.dt).min(200.0), 0.7)
                };
                let seed = seeded(nominal, |e| e.valve_dynamics = Some(d0));
                vec![
                    FreeParam::at_then(
                        "effects.valve_dynamics.natural_frequency",
                        (
                            std::f64::consts::TAU * 1.0,
                            std::f64::consts::TAU * (0.5 / sc.dt).min(3000.0),
                            true,
                            w0,
                        ),
                        &seed,
                        |p| {
                            if let Some(s) = p.effects.valve_dynamics.as_mut() {
                                s.order = 2;
                                if s.damping_ratio <= 0.0 {
                                    s.damping_ratio = 0.7;
                                }
                            }
                        },
                    ),
                    FreeParam::at_then(
                        "effects.valve_dynamics.damping_ratio",
                        (0.2, 2.0, false, z0),
                        &seed,
                        |p| {
                            if let Some(s) = p.effects.valve_dynamics.as_mut() {
                                s.order = 2;
                            }
                        },
                    ),
                ]
            }
        })
    }
}
