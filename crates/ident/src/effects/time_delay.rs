//! `time_delay`: transport / communication delay on the valve command. Model: `TimeDelay` in
//! crates/plant/src/effects/time_delay.rs.
//!
//! Seed: the lag the residual analysis finds (at least one sample; bounds 0…min(60·Δt, 0.2 s)).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::TimeDelay;
use ehactl_plant::{EffectId, PlantParams};

/// The catalogue effect `time_delay`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Other
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::ValveDynamics).then_some(super::valve_dynamics::DELAY_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, dt: f64) -> (f64, String) {
        an.lag_prior(dt)
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, an: &Analysis) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let cur = ef.time_delay.as_ref().map_or(0.0, |d| d.delay);
        let init = if cur > 0.0 { cur } else { an.lag.max(sc.dt) };
        let seed = seeded(nominal, |e| {
            e.time_delay.get_or_insert(TimeDelay {
                enabled: true,
                delay: init,
            });
        });
        Some(vec![at(
            "effects.time_delay.delay",
            (0.0, (60.0 * sc.dt).min(0.2), false, init),
            &seed,
        )])
    }
}
