//! Setpoint generators: step, ramp, sine, chirp (linear / logarithmic), static + dynamic
//! superposition (004: 785 N + ±196 N over 1–300 Hz, swept or stepped), random steps.
//! Each returns the value and its time derivative; none allocates.

use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Kind of setpoint.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SetpointKind {
    /// `initial` until `start`, then `final`.
    Step,
    /// Linear from `initial` to `final` over `duration` from `start`.
    Ramp,
    /// `offset + amplitude·sin(2π·f0·(t − start))`.
    Sine,
    /// `offset + amplitude·sin(φ(t))`, frequency f0 → f1 over `duration`.
    Chirp,
    /// `offset` reached by a ramp over `ramp_time`, then a chirp of `amplitude` superposed (004).
    StaticDynamic,
    /// Piecewise-constant random levels in [`initial`, `final`], held for `hold`.
    RandomSteps,
}

/// See [`Setpoint::envelope`].
pub fn envelope(c: &SetpointConfig) -> ((f64, &'static str), (f64, &'static str)) {
    let order = |a: (f64, &'static str), b: (f64, &'static str)| {
        if a.0 <= b.0 {
            (a, b)
        } else {
            (b, a)
        }
    };
    match c.kind {
        SetpointKind::Step | SetpointKind::Ramp | SetpointKind::RandomSteps => {
            order((c.initial, "initial"), (c.final_value, "final"))
        }
        SetpointKind::Sine | SetpointKind::Chirp => (
            (c.offset - c.amplitude, swing_field(c)),
            (c.offset + c.amplitude, swing_field(c)),
        ),
        // Ramp from 0 to `offset`, then the sweep around it.
        SetpointKind::StaticDynamic => (
            ((c.offset - c.amplitude).min(0.0), swing_field(c)),
            ((c.offset + c.amplitude).max(0.0), swing_field(c)),
        ),
    }
}

/// The field that puts `offset ± amplitude` where it is: the larger of the two in
/// magnitude (an out-of-range extreme names the value that sent it there).
fn swing_field(c: &SetpointConfig) -> &'static str {
    if c.amplitude.abs() >= c.offset.abs() {
        "amplitude"
    } else {
        "offset"
    }
}

/// Frequency sweep law.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Sweep {
    /// Linear in frequency.
    #[default]
    Linear,
    /// Logarithmic (exponential) in frequency.
    Log,
    /// Stepped sine: `steps` frequencies spaced logarithmically, each held for duration/steps.
    Stepped,
}

/// Setpoint section of a rig config. Units are those of the controlled variable (N or m).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct SetpointConfig {
    /// Generator kind.
    #[param(
        choice,
        desc = "generator: step, ramp, sine, chirp, static_dynamic (static + swept, 004) or random_steps"
    )]
    pub kind: SetpointKind,
    /// Start value (N or m) for step/ramp, lower bound for random steps.
    #[serde(default)]
    #[param(unit = "N or m", range = Finite, desc = "initial value / lower bound")]
    pub initial: f64,
    /// Final value (N or m) for step/ramp, upper bound for random steps.
    #[serde(default, rename = "final")]
    #[param(unit = "N or m", range = Finite, desc = "final value / upper bound")]
    pub final_value: f64,
    /// Start time (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "start time")]
    pub start: f64,
    /// Ramp or sweep duration (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "ramp / sweep duration")]
    pub duration: f64,
    /// Static part / offset (N or m).
    #[serde(default)]
    #[param(unit = "N or m", range = Finite, desc = "static part / offset")]
    pub offset: f64,
    /// Dynamic amplitude (N or m).
    #[serde(default)]
    #[param(unit = "N or m", range = NonNegative, desc = "dynamic amplitude")]
    pub amplitude: f64,
    /// Start (or sine) frequency (Hz).
    #[serde(default)]
    #[param(unit = "Hz", range = Within(0.0, 1.0e6), desc = "start frequency")]
    pub f0: f64,
    /// End frequency (Hz).
    #[serde(default)]
    #[param(unit = "Hz", range = Within(0.0, 1.0e6), desc = "end frequency")]
    pub f1: f64,
    /// Sweep law.
    #[serde(default)]
    #[param(
        choice,
        desc = "sweep law of chirp / static_dynamic: linear (default), log or stepped (`steps` frequencies)"
    )]
    pub sweep: Sweep,
    /// Number of frequencies of a stepped sweep (-).
    #[serde(default)]
    #[param(
        unit = "-",
        range = NonNegative,
        desc = "frequencies of a stepped sweep"
    )]
    pub steps: u32,
    /// Ramp time of the static part (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "static ramp time")]
    pub ramp_time: f64,
    /// Hold time of each random level (s).
    #[serde(default)]
    #[param(unit = "s", range = NonNegative, desc = "random-step hold time")]
    pub hold: f64,
    /// Seed of the random levels (-).
    #[serde(default)]
    #[param(unit = "-", range = NonNegative, desc = "random-step seed")]
    pub seed: u64,
}

/// A ready-to-sample setpoint generator.
#[derive(Debug, Clone)]
pub struct Setpoint {
    c: SetpointConfig,
    /// ln(f1/f0)/duration (1/s) of the log sweep, computed once.
    log_rate: f64,
}

fn hash01(seed: u64, k: u64) -> f64 {
    let mut z = seed ^ k.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

impl Setpoint {
    /// From a validated config section.
    pub fn new(c: &SetpointConfig) -> Self {
        Self {
            c: c.clone(),
            log_rate: (c.f1 / c.f0).ln() / c.duration.max(1e-12),
        }
    }

    /// The config.
    pub fn config(&self) -> &SetpointConfig {
        &self.c
    }

    /// Instantaneous frequency (Hz) and phase (rad) of the sweep at τ ≥ 0 s.
    pub fn sweep_phase(&self, tau: f64) -> (f64, f64) {
        let c = &self.c;
        let t_end = c.duration.max(1e-12);
        let tt = tau.min(t_end);
        let (f, mut ph) = match c.sweep {
            Sweep::Linear => {
                let k = (c.f1 - c.f0) / t_end;
                (c.f0 + k * tt, TAU * (c.f0 * tt + 0.5 * k * tt * tt))
            }
            Sweep::Log => {
                let r = self.log_rate;
                if r.abs() < 1e-12 {
                    (c.f0, TAU * c.f0 * tt)
                } else {
                    // One expm1 gives both f = f0·e^(rt) and φ = 2π·f0·(e^(rt) − 1)/r.
                    let em1 = (r * tt).exp_m1();
                    (c.f0 * (1.0 + em1), TAU * c.f0 * em1 / r)
                }
            }
            Sweep::Stepped => {
                let n = c.steps.max(1);
                let dwell = t_end / n as f64;
                let i = ((tt / dwell).floor() as u32).min(n - 1);
                let f = if n == 1 {
                    c.f0
                } else {
                    c.f0 * (c.f1 / c.f0).powf(i as f64 / (n - 1) as f64)
                };
                // Phase restarts at each dwell so each segment is a clean sine.
                (f, TAU * f * (tt - i as f64 * dwell))
            }
        };
        if tau > t_end {
            ph += TAU * f * (tau - t_end);
        }
        (f, ph)
    }

    /// Value and rate of change at time `t` (s).
    #[inline]
    pub fn sample(&self, t: f64) -> (f64, f64) {
        let c = &self.c;
        let tau = t - c.start;
        match c.kind {
            SetpointKind::Step => (if tau >= 0.0 { c.final_value } else { c.initial }, 0.0),
            SetpointKind::Ramp => {
                if tau <= 0.0 {
                    (c.initial, 0.0)
                } else if tau >= c.duration {
                    (c.final_value, 0.0)
                } else {
                    let k = (c.final_value - c.initial) / c.duration;
                    (c.initial + k * tau, k)
                }
            }
            SetpointKind::Sine => {
                if tau < 0.0 {
                    return (c.offset, 0.0);
                }
                let w = TAU * c.f0;
                (
                    c.offset + c.amplitude * (w * tau).sin(),
                    c.amplitude * w * (w * tau).cos(),
                )
            }
            SetpointKind::Chirp => {
                if tau < 0.0 {
                    return (c.offset, 0.0);
                }
                let (f, ph) = self.sweep_phase(tau);
                let (s, co) = ph.sin_cos();
                (c.offset + c.amplitude * s, c.amplitude * TAU * f * co)
            }
            SetpointKind::StaticDynamic => {
                if t < c.ramp_time {
                    let k = c.offset / c.ramp_time.max(1e-12);
                    return (k * t.max(0.0), k);
                }
                let td = t - c.ramp_time.max(c.start);
                if td < 0.0 {
                    return (c.offset, 0.0);
                }
                let (f, ph) = self.sweep_phase(td);
                let (s, co) = ph.sin_cos();
                (c.offset + c.amplitude * s, c.amplitude * TAU * f * co)
            }
            SetpointKind::RandomSteps => {
                if tau < 0.0 {
                    return (c.initial, 0.0);
                }
                let k = (tau / c.hold.max(1e-12)).floor() as u64;
                let r = hash01(c.seed, k);
                (c.initial + (c.final_value - c.initial) * r, 0.0)
            }
        }
    }

    /// Smallest and largest value the setpoint can take (its unit: N, m or V), with the
    /// config fields that set each bound (for error messages).
    pub fn envelope(&self) -> ((f64, &'static str), (f64, &'static str)) {
        envelope(&self.c)
    }

    /// Time (s) at which the dynamic part of the setpoint starts (for analysis windows).
    pub fn dynamic_start(&self) -> f64 {
        match self.c.kind {
            SetpointKind::StaticDynamic => self.c.ramp_time.max(self.c.start),
            _ => self.c.start,
        }
    }
}
