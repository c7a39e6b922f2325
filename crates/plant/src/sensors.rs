//! Sensor models: load cell (sensitivity, noise; tones as in 004 at 225/420 Hz from the sensor
//! stage, crates/plant/src/effects/sensor_tone.rs), chamber pressures, magnetostrictive
//! position transducer (resolution, update period), spool.

use crate::effects::{SensorChannel, SensorStage};
use crate::params::Sensors;
use crate::rng::NoiseRng;

pub use ehactl_types::Measurements;

/// True (noise-free) values the sensors look at.
#[derive(Debug, Clone, Copy)]
pub struct TrueValues {
    /// Time (s).
    pub t: f64,
    /// Rod force (N).
    pub force: f64,
    /// Position (m).
    pub position: f64,
    /// Pressure A (Pa).
    pub p_a: f64,
    /// Pressure B (Pa).
    pub p_b: f64,
    /// Spool (fraction).
    pub spool: f64,
}

/// Noise channels, in the order of their generator streams.
const CHANNELS: usize = 5;

/// Stateful sensor set.
///
/// Noise: one xoshiro256++ stream per channel (force 0, position 1, pressure A 2, pressure B
/// 3, spool 4), seeded from `sensors.seed` + k·0x9E3779B97F4A7C15 via SplitMix64 ([`NoiseRng`]);
/// a channel draws one standard normal per sample (the position one per transducer update)
/// only if its noise σ is non-zero. A channel's sequence thus depends only on the seed and
/// its own samples: switching noise on for one channel does not change another's.
#[derive(Debug, Clone)]
pub struct SensorModel {
    cfg: Sensors,
    rngs: [NoiseRng; CHANNELS],
    held_position: f64,
    next_position_update: f64,
}

impl SensorModel {
    /// From config.
    pub fn new(cfg: &Sensors) -> Self {
        Self {
            cfg: cfg.clone(),
            rngs: std::array::from_fn(|k| {
                NoiseRng::new(
                    cfg.seed
                        .wrapping_add((k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
                )
            }),
            held_position: f64::NAN,
            next_position_update: f64::NEG_INFINITY,
        }
    }

    /// σ·N(0, 1) from channel `k`'s stream, nothing drawn when σ = 0.
    #[inline]
    fn noise(&mut self, k: usize, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * self.rngs[k].normal()
        }
    }

    /// Sample every sensor, each channel's reading with what the sensor `stage` adds to it
    /// (the `sensor_tone` component). Does not allocate.
    pub fn sample(&mut self, v: &TrueValues, stage: &mut impl SensorStage) -> Measurements {
        let c = &self.cfg;
        let (sf, sx, sp, ss) = (
            c.force.noise,
            c.position.noise,
            c.pressure.noise,
            c.spool.noise,
        );
        let (res, upd) = (c.position.resolution, c.position.update_period);
        let force = v.force + self.noise(0, sf) + stage.add(SensorChannel::Force, v.t);
        if v.t + 1e-12 >= self.next_position_update {
            let mut x = v.position + self.noise(1, sx);
            if res > 0.0 {
                x = (x / res).round() * res;
            }
            self.held_position = x;
            self.next_position_update = if upd > 0.0 {
                let k = (v.t / upd).floor() + 1.0;
                k * upd
            } else {
                f64::NEG_INFINITY
            };
        }
        let position = self.held_position + stage.add(SensorChannel::Position, v.t);
        let p_a = v.p_a + self.noise(2, sp) + stage.add(SensorChannel::PressureA, v.t);
        let p_b = v.p_b + self.noise(3, sp) + stage.add(SensorChannel::PressureB, v.t);
        let spool = v.spool + self.noise(4, ss);
        Measurements {
            t: v.t,
            force,
            position,
            p_a,
            p_b,
            spool,
        }
    }
}
