//! Sensor models: load cell (sensitivity, noise, tones as in 004 at 225/420 Hz), chamber
//! pressures, magnetostrictive position transducer (resolution, update period), spool.

use crate::params::{SensorChannel, SensorTone, Sensors};
use crate::rng::NoiseRng;
use std::f64::consts::TAU;

/// One sample of every sensor, in SI units. A channel a backend lacks is NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurements {
    /// Sample time (s).
    pub t: f64,
    /// Rod / load-cell force (N).
    pub force: f64,
    /// Piston position (m).
    pub position: f64,
    /// Chamber A pressure (Pa).
    pub p_a: f64,
    /// Chamber B pressure (Pa).
    pub p_b: f64,
    /// Spool position (fraction of full travel).
    pub spool: f64,
}

impl Default for Measurements {
    fn default() -> Self {
        Self {
            t: 0.0,
            force: f64::NAN,
            position: f64::NAN,
            p_a: f64::NAN,
            p_b: f64::NAN,
            spool: f64::NAN,
        }
    }
}

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

/// Stateful sensor set.
#[derive(Debug, Clone)]
pub struct SensorModel {
    cfg: Sensors,
    tone: Option<SensorTone>,
    rng: NoiseRng,
    held_position: f64,
    next_position_update: f64,
}

impl SensorModel {
    /// From config; `tone` is the `sensor_tone` effect when enabled.
    pub fn new(cfg: &Sensors, tone: Option<&SensorTone>) -> Self {
        Self {
            cfg: cfg.clone(),
            tone: tone.filter(|t| t.enabled).cloned(),
            rng: NoiseRng::new(cfg.seed),
            held_position: f64::NAN,
            next_position_update: f64::NEG_INFINITY,
        }
    }

    fn tone(&self, ch: SensorChannel, t: f64) -> f64 {
        match &self.tone {
            Some(tone) if tone.channel == ch => tone
                .frequencies
                .iter()
                .zip(&tone.amplitudes)
                .enumerate()
                .map(|(i, (f, a))| a * (TAU * f * t + tone.phases.get(i).copied().unwrap_or(0.0)).sin())
                .sum(),
            _ => 0.0,
        }
    }

    /// Sample every sensor. Does not allocate.
    pub fn sample(&mut self, v: &TrueValues) -> Measurements {
        let c = &self.cfg;
        let force =
            v.force + c.force.noise * self.rng.normal() + self.tone(SensorChannel::Force, v.t);
        if v.t + 1e-12 >= self.next_position_update {
            let mut x = v.position + c.position.noise * self.rng.normal();
            if c.position.resolution > 0.0 {
                x = (x / c.position.resolution).round() * c.position.resolution;
            }
            self.held_position = x;
            self.next_position_update = if c.position.update_period > 0.0 {
                let k = (v.t / c.position.update_period).floor() + 1.0;
                k * c.position.update_period
            } else {
                f64::NEG_INFINITY
            };
        }
        let position = self.held_position + self.tone(SensorChannel::Position, v.t);
        let p_a =
            v.p_a + c.pressure.noise * self.rng.normal() + self.tone(SensorChannel::PressureA, v.t);
        let p_b =
            v.p_b + c.pressure.noise * self.rng.normal() + self.tone(SensorChannel::PressureB, v.t);
        let spool = v.spool + c.spool.noise * self.rng.normal();
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
