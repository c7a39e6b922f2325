//! `sensor_tone`: periodic disturbance a·sin(2πft + φ) on a sensor channel (004: 225 Hz and
//! 420 Hz on the load cell): the config section [`SensorTone`] (`[effects.sensor_tone]`) and
//! its component [`Tones`], the sensor stage ([`SensorStage`]) whose tones, each generated
//! by a `Tone`, the sensor model (crates/plant/src/sensors.rs) adds to their channel.

pub use super::component::SensorChannel;
use super::component::{Component, SensorStage, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

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

/// The component of `sensor_tone`: the tones of the section and the channel they are added
/// to; none without the effect.
#[derive(Debug, Clone)]
pub struct Tones {
    /// The channel, `None` without the effect.
    channel: Option<SensorChannel>,
    /// One generator per frequency (allocated in configure).
    tones: Vec<Tone>,
}

impl Component for Tones {
    type Section = SensorTone;

    /// One amplitude per frequency, and one phase per frequency or none.
    fn validate(s: &SensorTone) -> Result<(), ConfigError> {
        s.validate_amplitudes()?;
        s.validate_variant()
    }

    /// A generator a·sin(2πft + φ) per frequency (φ = 0 without `phases`); none for a section
    /// that is absent or switched off.
    fn configure(s: Option<&SensorTone>, _setup: &Setup) -> Self {
        let tone = s.filter(|t| t.enabled);
        Tones {
            channel: tone.map(|t| t.channel),
            tones: tone.map_or(Vec::new(), |t| {
                t.frequencies
                    .iter()
                    .zip(&t.amplitudes)
                    .enumerate()
                    .map(|(i, (f, a))| Tone::new(*f, *a, t.phases.get(i).copied().unwrap_or(0.0)))
                    .collect()
            }),
        }
    }

    /// Every generator back to its state before the first sample (no allocation).
    fn reset(&mut self) {
        self.tones.iter_mut().for_each(Tone::reset);
    }
}

impl SensorStage for Tones {
    /// The sum of the tones at `t` on the section's channel, 0 on the others (whose
    /// generators do not advance).
    #[inline]
    fn add(&mut self, ch: SensorChannel, t: f64) -> f64 {
        if self.channel != Some(ch) {
            return 0.0;
        }
        self.tones.iter_mut().map(|tone| tone.value(t)).sum()
    }
}

/// One tone A·sin(2π f t) evaluated by rotation: when consecutive sample times are equally
/// spaced (the control grid), (sin, cos) advance by one complex multiplication instead of a
/// `sin` call; any other spacing, and every [`Tone::RESYNC`]-th sample, recomputes them
/// exactly, so the rounding drift stays below 1e-13 of the amplitude.
#[derive(Debug, Clone)]
struct Tone {
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

    fn new(freq: f64, amp: f64, ph: f64) -> Self {
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

    /// Back to the state of [`Tone::new`] (before the first sample).
    fn reset(&mut self) {
        self.s = 0.0;
        self.c = 1.0;
        self.t_last = f64::NAN;
        self.dt = f64::NAN;
        self.rot = (0.0, 1.0);
        self.since_sync = 0;
    }

    /// amp·sin(w·t + φ) (the channel's unit) at `t` (s).
    #[inline]
    fn value(&mut self, t: f64) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

    const SETUP: Setup = Setup::TEST;

    fn section() -> SensorTone {
        SensorTone {
            enabled: true,
            channel: SensorChannel::PressureA,
            frequencies: vec![225.0, 420.0],
            amplitudes: vec![2.0, 0.5],
            phases: vec![0.3, -1.0],
        }
    }

    /// a·sin(2πft + φ) summed over the tones on its channel, within the rotation's rounding
    /// (1e-13 of the amplitude) on the control grid; nothing on the other channels.
    #[test]
    fn adds_the_tones_to_its_channel_only() {
        let mut st = Tones::configure(Some(&section()), &SETUP);
        for k in 0..3000 {
            let t = k as f64 * 2e-4;
            let want = 2.0 * (TAU * 225.0 * t + 0.3).sin() + 0.5 * (TAU * 420.0 * t - 1.0).sin();
            let got = st.add(SensorChannel::PressureA, t);
            assert!((got - want).abs() < 1e-11, "t {t}: {got} vs {want}");
            assert_eq!(st.add(SensorChannel::Force, t), 0.0);
        }
    }

    /// Without the effect (absent or switched off) nothing is added anywhere.
    #[test]
    fn without_the_effect_nothing_is_added() {
        let mut off = section();
        off.enabled = false;
        for s in [None, Some(&off)] {
            let mut st = Tones::configure(s, &SETUP);
            for ch in [
                SensorChannel::Force,
                SensorChannel::Position,
                SensorChannel::PressureA,
                SensorChannel::PressureB,
            ] {
                assert_eq!(st.add(ch, 0.0123), 0.0);
            }
        }
    }

    /// After a reset the samples are bit for bit those of a new component (the rotation
    /// restarts from an exact sample and its resync count from 0).
    #[test]
    fn reset_repeats_the_samples_of_a_new_component() {
        let run = |st: &mut Tones| -> Vec<f64> {
            (0..3000)
                .map(|k| st.add(SensorChannel::PressureA, k as f64 * 1e-4 + 0.5))
                .collect()
        };
        let fresh = run(&mut Tones::configure(Some(&section()), &SETUP));
        let mut st = Tones::configure(Some(&section()), &SETUP);
        run(&mut st);
        st.add(SensorChannel::PressureA, 0.123);
        st.reset();
        assert_eq!(fresh, run(&mut st));
    }

    /// The component's checks: one amplitude per frequency, one phase per frequency or none.
    #[test]
    fn validate_counts_amplitudes_and_phases() {
        assert!(Tones::validate(&section()).is_ok());
        let mut s = section();
        s.amplitudes.pop();
        let e = Tones::validate(&s).unwrap_err();
        assert!(
            e.to_string().contains("effects.sensor_tone.amplitudes"),
            "{e}"
        );
        let mut s = section();
        s.phases.pop();
        let e = Tones::validate(&s).unwrap_err();
        assert!(e.to_string().contains("effects.sensor_tone.phases"), "{e}");
        s.phases.clear();
        assert!(Tones::validate(&s).is_ok());
    }
}
