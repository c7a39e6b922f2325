//! `sensor_tone`: periodic disturbance a·sin(2πft + φ) on a sensor channel (004: 225 Hz and
//! 420 Hz on the load cell): the config section [`SensorTone`] (`[effects.sensor_tone]`) and
//! one tone's generator, `Tone`, which the sensor model (crates/plant/src/sensors.rs) adds to
//! its channel.

use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Sensor channel a tone is added to.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SensorChannel {
    /// Load cell force (N).
    Force,
    /// Piston position (m).
    Position,
    /// Chamber A pressure (Pa).
    PressureA,
    /// Chamber B pressure (Pa).
    PressureB,
}

/// `sensor_tone`: periodic disturbance on a sensor (004: 225 Hz and 420 Hz on the load cell).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SensorTone {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Channel the tones are added to.
    #[serde(default = "SensorTone::default_channel")]
    pub channel: SensorChannel,
    /// Tone frequencies (Hz).
    #[param(unit = "Hz", range = Positive, desc = "tone frequencies (004: 225, 420)")]
    pub frequencies: Vec<f64>,
    /// Tone amplitudes in the channel's unit (N, m or Pa), one per frequency.
    #[param(unit = "channel unit", range = NonNegative, desc = "tone amplitudes")]
    pub amplitudes: Vec<f64>,
    /// Tone phases φ (rad), one per frequency (empty = all 0): a·sin(2πft + φ).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[param(unit = "rad", range = Finite, desc = "tone phases φ in a·sin(2πft + φ), one per frequency (default 0)")]
    pub phases: Vec<f64>,
}

impl SensorTone {
    fn default_channel() -> SensorChannel {
        SensorChannel::Force
    }
}

impl SensorTone {
    /// Check: one amplitude per frequency.
    pub(crate) fn validate_amplitudes(&self) -> Result<(), ConfigError> {
        if self.frequencies.len() != self.amplitudes.len() {
            return Err(ConfigError::new(
                "effects.sensor_tone.amplitudes",
                format!(
                    "{} amplitudes for {} frequencies; expected one amplitude per frequency",
                    self.amplitudes.len(),
                    self.frequencies.len()
                ),
            ));
        }
        Ok(())
    }
}

impl SensorTone {
    /// Cross-field check: one phase per frequency, or none.
    pub(crate) fn validate_variant(&self) -> Result<(), ConfigError> {
        if !self.phases.is_empty() && self.phases.len() != self.frequencies.len() {
            return Err(ConfigError::new(
                "effects.sensor_tone.phases",
                format!(
                    "{} phases for {} frequencies; expected one phase (rad) per frequency or none",
                    self.phases.len(),
                    self.frequencies.len()
                ),
            ));
        }
        Ok(())
    }
}

/// One tone A·sin(2π f t) evaluated by rotation: when consecutive sample times are equally
/// spaced (the control grid), (sin, cos) advance by one complex multiplication instead of a
/// `sin` call; any other spacing, and every [`Tone::RESYNC`]-th sample, recomputes them
/// exactly, so the rounding drift stays below 1e-13 of the amplitude.
#[derive(Debug, Clone)]
pub(crate) struct Tone {
    w: f64,
    /// Phase φ (rad): amp·sin(w·t + φ).
    ph: f64,
    amp: f64,
    s: f64,
    c: f64,
    t_last: f64,
    dt: f64,
    rot: (f64, f64),
    since_sync: u32,
}

impl Tone {
    const RESYNC: u32 = 1024;

    pub(crate) fn new(freq: f64, amp: f64, ph: f64) -> Self {
        Self {
            w: TAU * freq,
            ph,
            amp,
            s: 0.0,
            c: 1.0,
            t_last: f64::NAN,
            dt: f64::NAN,
            rot: (0.0, 1.0),
            since_sync: 0,
        }
    }

    #[inline]
    pub(crate) fn value(&mut self, t: f64) -> f64 {
        let dt = t - self.t_last;
        if dt == self.dt || (dt - self.dt).abs() <= 1e-12 * self.dt.abs() {
            if self.since_sync < Self::RESYNC {
                let (sd, cd) = self.rot;
                let s = self.s * cd + self.c * sd;
                self.c = self.c * cd - self.s * sd;
                self.s = s;
                self.since_sync += 1;
                self.t_last = t;
                return self.amp * self.s;
            }
        } else if dt.is_finite() && dt > 0.0 {
            self.dt = dt;
            self.rot = (self.w * dt).sin_cos();
        }
        let (s, c) = (self.w * t + self.ph).sin_cos();
        self.s = s;
        self.c = c;
        self.since_sync = 0;
        self.t_last = t;
        self.amp * s
    }
}
