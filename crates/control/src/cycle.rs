//! The control cycle kernel: one plain step function from a cycle's measurements to the
//! command it applies, in the style of a copper-rs task (`process(input) → output`, no I/O,
//! no clock, no allocation, no lock). The one loop body that `ehactl run`'s cycle
//! (`ehactl_runtime::runloop`, between `Hal::read` and `Hal::write`) and the diagnosis's
//! replay (`ehactl_ident::replay`, between `Plant::measure` and `Plant::step`) both step, so
//! the two can never disagree about what a cycle does.
//!
//! One [`step`] is, in order:
//! 1. the reference sample `(r, ṙ)` of the cycle from a [`Reference`] source (the
//!    configured [`Setpoint`] in a run, a recorded column in a replay, [`Recorded`]);
//! 2. the supervisor's sensor checks ([`Supervisor::check_sensors`]); a trip there holds
//!    the safe command and the law is not stepped ([`Trip::Sensors`]);
//! 3. the control law ([`Controller::step`]) on the measured feedback;
//! 4. the supervisor's watches on the law's terms ([`Supervisor::check_terms`]), the command
//!    limit ([`Supervisor::limit_command`]), the saturation and following-error watches
//!    ([`Supervisor::check_saturation`], [`Supervisor::check_following`]).
//!
//! The caller owns everything around it: where the measurements come from, where the
//! command goes, the record and the events. A caller that has no supervisor of its own
//! (a replay) passes one with only the command limit set ([`Supervisor::new`] with a
//! [`crate::supervisor::SupervisorConfig`] whose watches are absent).
//!
//! ```
//! use ehactl_control::controller::Controller;
//! use ehactl_control::cycle::{self, CycleInput, Recorded};
//! use ehactl_control::pd::{Pd, PdGains};
//! use ehactl_control::supervisor::{Supervisor, SupervisorConfig};
//! use ehactl_types::Measurements;
//!
//! let gains = PdGains { kp: 100.0, td: 0.0, filter_n: 0.0, u_max: 10.0, feedforward_velocity: 0.0 };
//! let mut law = Controller::Position(Pd::new(gains));
//! let cfg = SupervisorConfig { max_command: Some(5.0), ..SupervisorConfig::default() };
//! let mut supervisor = Supervisor::new(&cfg, law.feedback_channel());
//! let reference = [0.1, 0.1];
//! let meas = Measurements { t: 0.0, position: 0.08, force: 0.0, ..Measurements::default() };
//! let input = CycleInput { k: 0, t: 0.0, dt: 2e-4, meas };
//! let out = cycle::step(&mut law, &mut supervisor, &Recorded::new(&reference), &input);
//! assert!(out.trip.is_none());
//! assert!((out.u - 2.0).abs() < 1e-12); // k_p · (r − x) = 100 V/m · 0.02 m
//! ```

use crate::controller::Controller;
use crate::pi::ControlTerms;
use crate::setpoint::Setpoint;
use crate::supervisor::Supervisor;
use ehactl_types::event::Event;
use ehactl_types::Measurements;

/// Where a cycle's reference comes from: the setpoint `r` (N, m or V, the law's unit) and
/// its rate `ṙ` (per s) of cycle `k` at time `t` (s). Pure: sampling does not advance it.
pub trait Reference {
    /// The reference `(r, ṙ)` of cycle `k` at `t` (s).
    fn sample(&self, k: u64, t: f64) -> (f64, f64);
}

impl Reference for Setpoint {
    /// The configured generator at `t` ([`Setpoint::sample`]).
    #[inline]
    fn sample(&self, _k: u64, t: f64) -> (f64, f64) {
        Setpoint::sample(self, t)
    }
}

/// A recorded reference: sample `k` of a column (the law's unit) with rate 0 (a record
/// has no setpoint rate); NaN past its end, which the supervisor's watch on the law's
/// terms turns into a trip.
#[derive(Debug, Clone, Copy)]
pub struct Recorded<'a> {
    values: &'a [f64],
}

impl<'a> Recorded<'a> {
    /// The column `values`, one sample per cycle.
    pub fn new(values: &'a [f64]) -> Self {
        Self { values }
    }
}

impl Reference for Recorded<'_> {
    #[inline]
    fn sample(&self, k: u64, _t: f64) -> (f64, f64) {
        let r = usize::try_from(k)
            .ok()
            .and_then(|k| self.values.get(k))
            .copied()
            .unwrap_or(f64::NAN);
        (r, 0.0)
    }
}

/// What one cycle is given: its index, time and period, and the measurements read for it.
#[derive(Debug, Clone, Copy)]
pub struct CycleInput {
    /// Cycle index (from 0).
    pub k: u64,
    /// Time of the cycle (s).
    pub t: f64,
    /// Control period (s) the law and the watches integrate over.
    pub dt: f64,
    /// The measurements of the cycle (SI units).
    pub meas: Measurements,
}

/// How a cycle ended in a trip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Trip {
    /// A sensor check failed before the law: the cycle holds the safe command (its terms
    /// are the held ones, [`CycleOutput::terms`]) and a run records it.
    Sensors(Event),
    /// The law's terms, its command or a watch after it tripped: a run does not record the
    /// cycle (the command never reached the valve).
    Law(Event),
}

/// What one cycle decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleOutput {
    /// The reference `(r, ṙ)` of the cycle.
    pub reference: (f64, f64),
    /// The measured value the law feeds back (N or m, [`Controller::feedback`]).
    pub feedback: f64,
    /// The law's terms (V); on a sensor trip the held ones: the safe command, the error
    /// `r − feedback` (NaN in open loop) and NaN terms.
    pub terms: ControlTerms,
    /// The command to apply (V): the law's command within the supervisor's limit, or the
    /// safe command on a trip.
    pub u: f64,
    /// A warning to log before anything else of the cycle (the first command clamp).
    pub warning: Option<Event>,
    /// The trip that ends the run, if any.
    pub trip: Option<Trip>,
}

/// One control cycle: reference, sensor checks, law, command limit and watches (see the
/// module documentation). Allocation-free and lock-free; `law` and `supervisor` carry the
/// state from cycle to cycle.
#[inline]
pub fn step<R: Reference + ?Sized>(
    law: &mut Controller,
    supervisor: &mut Supervisor,
    reference: &R,
    input: &CycleInput,
) -> CycleOutput {
    let (k, t, dt) = (input.k, input.t, input.dt);
    let meas = &input.meas;
    let (r, rdot) = reference.sample(k, t);
    let feedback = law.feedback(meas);
    let mut out = CycleOutput {
        reference: (r, rdot),
        feedback,
        terms: ControlTerms::default(),
        u: supervisor.safe_command(),
        warning: None,
        trip: None,
    };
    if let Some(ev) = supervisor.check_sensors(t, k, meas) {
        let safe = out.u;
        let e = if matches!(law, Controller::OpenLoop) {
            f64::NAN
        } else {
            r - feedback
        };
        out.terms = ControlTerms {
            u: safe,
            u_unsat: safe,
            error: e,
            p: f64::NAN,
            i: f64::NAN,
            d: f64::NAN,
            ff: f64::NAN,
        };
        out.trip = Some(Trip::Sensors(ev));
        return out;
    }
    let terms = law.step(r, rdot, meas, dt);
    out.terms = terms;
    if let Some(ev) = supervisor.check_terms(t, k, &terms) {
        out.trip = Some(Trip::Law(ev));
        return out;
    }
    let (u, ev) = supervisor.limit_command(t, k, terms.u);
    if let Some(ev) = ev {
        if ev.severity == ehactl_types::event::Severity::Trip {
            out.trip = Some(Trip::Law(ev));
            return out;
        }
        out.warning = Some(ev);
    }
    let saturated = terms.u != terms.u_unsat || u != terms.u;
    out.trip = supervisor
        .check_saturation(t, k, saturated, dt)
        .or_else(|| supervisor.check_following(t, k, terms.error, dt))
        .map(Trip::Law);
    if out.trip.is_none() {
        out.u = u;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pi::{Pi, PiGains};
    use crate::supervisor::SupervisorConfig;

    fn meas(t: f64, force: f64) -> Measurements {
        Measurements {
            t,
            force,
            ..Measurements::default()
        }
    }

    /// The kernel applies exactly what the law and the clamp give, step by step: a PI loop
    /// on a recorded reference against the same law stepped by hand and clamped with
    /// `clamp_command`.
    #[test]
    fn the_kernel_is_the_law_then_the_clamp() {
        let gains = PiGains {
            kp: 5.0,
            integral: 40.0,
            error_scale: 1e-3,
            u_min: -10.0,
            u_max: 10.0,
            tracking: 0.0,
            feedforward: 0.0,
        };
        let cfg = SupervisorConfig {
            max_command: Some(2.0),
            ..SupervisorConfig::default()
        };
        let mut law = Controller::Force(Pi::new(gains));
        let mut by_hand = Pi::new(gains);
        let mut sup = Supervisor::new(&cfg, law.feedback_channel());
        let r: Vec<f64> = (0..50).map(|k| 1000.0 * (k as f64 * 0.3).sin()).collect();
        let src = Recorded::new(&r);
        let mut warned = 0;
        for k in 0..50u64 {
            let t = k as f64 * 1e-3;
            let m = meas(t, 300.0 * (k as f64 * 0.1).cos());
            let out = step(
                &mut law,
                &mut sup,
                &src,
                &CycleInput {
                    k,
                    t,
                    dt: 1e-3,
                    meas: m,
                },
            );
            let want = by_hand.step(r[k as usize], m.force, 1e-3);
            assert!(out.trip.is_none());
            assert_eq!(out.terms, want);
            assert_eq!(
                out.u.to_bits(),
                crate::supervisor::clamp_command(want.u, 2.0).to_bits()
            );
            warned += usize::from(out.warning.is_some());
        }
        // The clamp is reported once.
        assert_eq!(warned, 1);
    }

    /// A non-finite feedback trips before the law (which keeps its state) and holds the
    /// safe command; a reference past the record's end trips after the law.
    #[test]
    fn trips_hold_the_safe_command() {
        let cfg = SupervisorConfig {
            safe_command: -0.5,
            ..SupervisorConfig::default()
        };
        let gains = PiGains {
            kp: 1.0,
            integral: 1.0,
            error_scale: 1.0,
            u_min: -10.0,
            u_max: 10.0,
            tracking: 0.0,
            feedforward: 0.0,
        };
        let mut law = Controller::Force(Pi::new(gains));
        let mut sup = Supervisor::new(&cfg, law.feedback_channel());
        let r = [1.0];
        let src = Recorded::new(&r);
        let nan = CycleInput {
            k: 0,
            t: 0.0,
            dt: 1e-3,
            meas: meas(0.0, f64::NAN),
        };
        let out = step(&mut law, &mut sup, &src, &nan);
        assert!(matches!(out.trip, Some(Trip::Sensors(_))));
        assert_eq!(out.u, -0.5);
        assert_eq!(out.terms.u, -0.5);
        assert!(out.terms.error.is_nan());
        let past = CycleInput {
            k: 1,
            t: 1e-3,
            dt: 1e-3,
            meas: meas(1e-3, 0.0),
        };
        let out = step(&mut law, &mut sup, &src, &past);
        assert!(matches!(out.trip, Some(Trip::Law(_))));
        assert_eq!(out.u, -0.5);
    }
}
