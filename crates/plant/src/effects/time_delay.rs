//! `time_delay`: transport / communication delay on the valve command (docs/design.md: the
//! CAN backend's SYNC-to-RPDO latency, a controller's computation time): the config section
//! [`TimeDelay`] (`[effects.time_delay]`) and its component [`DelayLine`], the command-path
//! stage that holds the commands of past control periods and gives the valve the command
//! sent τ earlier, u_valve(t) = u(t − τ), as a fractional delay (the mean over each substep,
//! see [`DelayLine::command`]).

use super::component::{CommandStage, Component, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// `time_delay`: transport / communication delay on the valve command.
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TimeDelay {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Delay (s).
    #[param(unit = "s", range = Within(0.0, 1.0), desc = "command delay", uncertain(order = 15, to_range_end, role = loop_param))]
    pub delay: f64,
}

/// The command delay τ (s) of the section `s`: 0 when it is absent or switched off. The one
/// reading of the section: the plant's [`DelayLine`] and the frequency-domain analysis
/// (e^(−jωτ) beside the linearised plant) both take τ from here.
pub fn delay(s: Option<&TimeDelay>) -> f64 {
    s.filter(|d| d.enabled).map_or(0.0, |d| d.delay)
}

/// The delay line of `time_delay`: a ring buffer of the commands (V) of the last control
/// periods. Without the effect it holds one slot, the present command, and passes it on.
#[derive(Debug, Clone)]
pub struct DelayLine {
    /// Delay τ (s), 0 without the effect.
    delay: f64,
    /// Control period T (s).
    control_dt: f64,
    /// Command (V) of period k at slot k mod len; len = ⌈τ/T⌉ + 2 periods with the effect
    /// (the two commands a substep may mix and every one between), 1 without.
    buf: Vec<f64>,
}

impl Component for DelayLine {
    type Section = TimeDelay;

    /// The delay is at most 1 s (a line of ⌈1 s / T⌉ + 2 slots).
    fn validate(s: &TimeDelay) -> Result<(), ConfigError> {
        if s.delay > 1.0 {
            return Err(ConfigError::new(
                "effects.time_delay.delay",
                "must be ≤ 1 s",
            ));
        }
        Ok(())
    }

    fn configure(s: Option<&TimeDelay>, setup: &Setup) -> Self {
        let delay = delay(s);
        let len = if delay > 0.0 {
            (delay / setup.control_dt).ceil() as usize + 2
        } else {
            1
        };
        DelayLine {
            delay,
            control_dt: setup.control_dt,
            buf: vec![0.0; len],
        }
    }

    /// Every past command 0 V (the valve saw no command before the run).
    fn reset(&mut self) {
        self.buf.iter_mut().for_each(|u| *u = 0.0);
    }
}

impl CommandStage for DelayLine {
    #[inline]
    fn push(&mut self, cycle: u64, u: f64) {
        let len = self.buf.len() as u64;
        self.buf[(cycle % len) as usize] = u;
    }

    /// The mean of the delayed zero-order-hold command over the substep. The delayed command
    /// switches at k·T + τ, which falls inside a substep unless τ is a multiple of h; the
    /// mean weights the two commands by their share of the substep, so the response is
    /// continuous in τ (a fractional delay) instead of stepping with the substep: with the
    /// command taken at the substep's start, the position error of the MTS loop stepped by
    /// 2.6e-5 NRMSE per 0.4 ms substep (crates/ident/examples/loop_delay_scan.rs), flat
    /// between, which a delay fit cannot resolve below a substep. Commands before the first
    /// one are 0 V.
    #[inline]
    fn command(&self, cycle: u64, t: f64, h: f64) -> f64 {
        if self.delay <= 0.0 {
            return self.buf[0];
        }
        let at = |k: u64| -> f64 {
            let k = k.min(cycle);
            let len = self.buf.len() as u64;
            if cycle - k >= len {
                return 0.0;
            }
            self.buf[(k % len) as usize]
        };
        let td = t - self.delay;
        if td + h <= 0.0 {
            return 0.0;
        }
        if td < 0.0 {
            // The first command arrives within this substep (nothing before it).
            return at(0) * (td + h) / h;
        }
        let k = (td / self.control_dt + 1e-9).floor() as u64;
        // Switch to command k + 1 at (k + 1)·T + τ, if within the substep (h ≤ T: at most
        // one switch).
        let ts = (k + 1) as f64 * self.control_dt - td;
        if ts >= h * (1.0 - 1e-9) || k + 1 > cycle {
            return at(k);
        }
        (at(k) * ts + at(k + 1) * (h - ts)) / h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(delay: f64, control_dt: f64) -> DelayLine {
        let s = TimeDelay {
            enabled: true,
            delay,
        };
        DelayLine::configure(
            Some(&s),
            &Setup {
                control_dt,
                supply_pressure: 20e6,
                bulk_modulus: 1.5e9,
                ..Setup::TEST
            },
        )
    }

    /// The mean over [t, t + h] of u(s − τ), u held over each period of `us` (0 V before
    /// the first), integrated piece by piece between the switch times k·T + τ.
    fn exact_mean(us: &[f64], dt: f64, tau: f64, t: f64, h: f64) -> f64 {
        let mut sum = 0.0;
        let mut a = t;
        while a < t + h - 1e-15 {
            let s = a - tau;
            let (u, next) = if s < 0.0 {
                (0.0, tau)
            } else {
                let k = (s / dt + 1e-9).floor();
                (us[k as usize], (k + 1.0) * dt + tau)
            };
            let b = next.min(t + h).max(a + 1e-15);
            sum += u * (b - a);
            a = b;
        }
        sum / h
    }

    /// A 3.3-period delay with 4 substeps per period over 500 periods (the ring buffer wraps
    /// 90 times): every substep's command is the exact mean of the delayed signal.
    #[test]
    fn fractional_delay_is_the_mean_of_the_delayed_hold() {
        let (dt, tau, n_sub) = (1e-3, 3.3e-3, 4u64);
        let h = dt / n_sub as f64;
        let mut l = line(tau, dt);
        assert_eq!(l.buf.len(), 6, "⌈3.3⌉ + 2 slots");
        let us: Vec<f64> = (0..500).map(|k| ((k * 37) % 11) as f64 - 5.0).collect();
        for (k, &u) in us.iter().enumerate() {
            l.push(k as u64, u);
            for i in 0..n_sub {
                let t = k as f64 * dt + i as f64 * h;
                let got = l.command(k as u64, t, h);
                let want = exact_mean(&us, dt, tau, t, h);
                assert!((got - want).abs() < 1e-9, "k {k} i {i}: {got} vs {want}");
            }
        }
    }

    /// Without the effect (absent or switched off) the valve sees the present command.
    #[test]
    fn without_the_effect_the_command_passes() {
        let off = TimeDelay {
            enabled: false,
            delay: 0.01,
        };
        for s in [None, Some(&off)] {
            let mut l = DelayLine::configure(
                s,
                &Setup {
                    control_dt: 1e-3,
                    supply_pressure: 20e6,
                    bulk_modulus: 1.5e9,
                    ..Setup::TEST
                },
            );
            assert_eq!((l.delay, l.buf.len()), (0.0, 1));
            for k in 0..5u64 {
                l.push(k, k as f64 + 0.5);
                assert_eq!(l.command(k, k as f64 * 1e-3, 5e-4), k as f64 + 0.5);
            }
        }
    }

    /// A reset empties the line (every slot 0 V); the new run's first command reaches the
    /// valve τ after it is sent, as in a fresh line.
    #[test]
    fn reset_empties_the_line() {
        let (dt, tau) = (1e-3, 2e-3);
        let mut l = line(tau, dt);
        for k in 0..10u64 {
            l.push(k, 7.0);
        }
        assert!(l.buf.iter().all(|&u| u == 7.0));
        l.reset();
        assert!(l.buf.iter().all(|&u| u == 0.0));
        for k in 0..4u64 {
            l.push(k, 1.0);
            let want = if k < 2 { 0.0 } else { 1.0 };
            assert_eq!(l.command(k, k as f64 * dt, dt), want, "period {k}");
        }
    }

    /// Delays over 1 s are refused, naming the parameter.
    #[test]
    fn validate_refuses_more_than_a_second() {
        let mut s = TimeDelay {
            enabled: true,
            delay: 1.0,
        };
        assert!(DelayLine::validate(&s).is_ok());
        s.delay = 1.5;
        let e = DelayLine::validate(&s).unwrap_err();
        assert!(e.to_string().contains("effects.time_delay.delay"), "{e}");
    }
}
