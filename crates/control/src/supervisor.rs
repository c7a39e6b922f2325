//! Supervisor: limits on pressure, position, force and command; sensor plausibility (NaN,
//! out of range, stale). On a trip the loop puts the valve to `safe_command`, logs the
//! event and ends the run with the reason. Checks are allocation-free.

use ehactl_params_derive::Params;
use ehactl_types::event::{Event, EventKind, Severity};
use ehactl_types::Measurements;
use serde::{Deserialize, Serialize};

/// Supervisor section of a rig config. Absent limits are not checked.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct SupervisorConfig {
    /// Trip when a chamber pressure exceeds this (Pa).
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "pressure trip limit")]
    pub max_pressure: Option<f64>,
    /// Trip below this position (m).
    #[serde(default)]
    #[param(unit = "m", range = Finite, desc = "lower position trip limit")]
    pub min_position: Option<f64>,
    /// Trip above this position (m).
    #[serde(default)]
    #[param(unit = "m", range = Finite, desc = "upper position trip limit")]
    pub max_position: Option<f64>,
    /// Trip when |force| exceeds this (N).
    #[serde(default)]
    #[param(unit = "N", range = Positive, desc = "force trip limit")]
    pub max_force: Option<f64>,
    /// Largest |command| passed to the valve (V); larger commands are clamped and reported once.
    #[serde(default)]
    #[param(unit = "V", range = Positive, desc = "command clamp")]
    pub max_command: Option<f64>,
    /// Command applied on a trip and at the end of the run (V).
    #[serde(default)]
    #[param(unit = "V", range = Finite, desc = "command on trip / end")]
    pub safe_command: f64,
    /// A sensor whose sample time does not advance for this long is stale (s).
    #[serde(default = "SupervisorConfig::default_stale")]
    #[param(unit = "s", range = Positive, desc = "sensor staleness timeout")]
    pub stale_timeout: f64,
    /// Plausible force range of the load cell (N): beyond it the reading is implausible.
    #[serde(default)]
    #[param(unit = "N", range = Positive, desc = "plausible load-cell range")]
    pub force_range: Option<f64>,
    /// Saturation watch (s): when set, the run trips once the command has been at a limit
    /// (the law's own or `max_command`) for more than `max_saturation` of an exponentially
    /// weighted window of this length. Catches a loop stuck against a limit and bang-bang
    /// limit cycling (e.g. after an absurd live gain). Off when absent.
    #[serde(default)]
    #[param(
        unit = "s",
        range = Within(1e-4, 1e3),
        desc = "trip when the command sits at a limit for > max_saturation of this window (absent = off)"
    )]
    pub saturation_window: Option<f64>,
    /// Share of the saturation window the command may spend at a limit (-).
    #[serde(default = "SupervisorConfig::default_max_saturation")]
    #[param(
        unit = "-",
        range = Within(0.01, 0.999),
        desc = "share of the saturation window allowed at a limit"
    )]
    pub max_saturation: f64,
    /// Plausible pressure range (Pa): readings outside [−1e5, this] are implausible.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "plausible pressure range")]
    pub pressure_range: Option<f64>,
    /// Following-error bound (N for a force loop, m for a position loop): the run trips once
    /// |setpoint − feedback| has been above it for longer than `following_error_time` (see
    /// [`Supervisor::check_following`]). Absent in a closed loop: a default derived from the
    /// setpoint (`RigConfig::supervisor_settings` in crates/config). Not allowed in open
    /// loop, which has no feedback.
    #[serde(default)]
    #[param(
        unit = "N or m",
        range = Positive,
        desc = "following-error bound on |setpoint − feedback| (absent: twice the largest |setpoint|, at least 10 % of the stroke / force capacity)"
    )]
    pub following_error: Option<f64>,
    /// How long (s) the error may stay above `following_error` before the run trips.
    #[serde(default = "SupervisorConfig::default_following_error_time")]
    #[param(
        unit = "s",
        range = Within(1e-4, 1e3),
        desc = "time the error may stay above the following-error bound"
    )]
    pub following_error_time: f64,
}

impl SupervisorConfig {
    fn default_stale() -> f64 {
        0.05
    }
    fn default_max_saturation() -> f64 {
        0.9
    }
    /// Default following-error time (s): a loop that is half a second away from its
    /// setpoint by more than the bound is not following it.
    pub fn default_following_error_time() -> f64 {
        0.5
    }
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        Self {
            max_pressure: None,
            min_position: None,
            max_position: None,
            max_force: None,
            max_command: None,
            safe_command: 0.0,
            stale_timeout: Self::default_stale(),
            force_range: None,
            pressure_range: None,
            saturation_window: None,
            max_saturation: Self::default_max_saturation(),
            following_error: None,
            following_error_time: Self::default_following_error_time(),
        }
    }
}

/// Which channels feed the controller (checked for NaN and staleness).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeedbackChannel {
    /// Load cell.
    Force,
    /// Position transducer.
    Position,
}

/// Runtime supervisor.
#[derive(Debug, Clone)]
pub struct Supervisor {
    cfg: SupervisorConfig,
    feedback: FeedbackChannel,
    last_sample_t: f64,
    last_advance_t: f64,
    command_clamped_reported: bool,
    /// Exponentially weighted share of recent cycles spent at a command limit (-).
    saturated_share: f64,
    /// Following-error debounce count (s): up by the period above the bound, down below.
    following_over: f64,
}

impl Supervisor {
    /// New supervisor for a loop closed on `feedback`.
    pub fn new(cfg: &SupervisorConfig, feedback: FeedbackChannel) -> Self {
        Self {
            cfg: cfg.clone(),
            feedback,
            last_sample_t: f64::NEG_INFINITY,
            last_advance_t: 0.0,
            command_clamped_reported: false,
            saturated_share: 0.0,
            following_over: 0.0,
        }
    }

    /// Safe valve command (V).
    pub fn safe_command(&self) -> f64 {
        self.cfg.safe_command
    }

    fn trip(
        t: f64,
        cycle: u64,
        kind: EventKind,
        channel: &'static str,
        value: f64,
        limit: f64,
        unit: &'static str,
    ) -> Event {
        Event {
            t,
            cycle,
            severity: Severity::Trip,
            kind,
            channel,
            value,
            limit,
            unit,
        }
    }

    /// Trip when a term of the control law is not finite (a feed-forward, gain or integrator
    /// that overflowed): clamping ±∞ to the command limits would otherwise pin the valve at
    /// a limit while the run goes on. The event names the term (V).
    #[inline]
    pub fn check_terms(
        &mut self,
        t: f64,
        cycle: u64,
        terms: &crate::pi::ControlTerms,
    ) -> Option<Event> {
        let named = [
            ("p_term", terms.p),
            ("i_term", terms.i),
            ("d_term", terms.d),
            ("ff_term", terms.ff),
            ("command_unsat", terms.u_unsat),
        ];
        named
            .iter()
            .find(|(_, v)| !v.is_finite())
            .map(|&(name, v)| Self::trip(t, cycle, EventKind::CommandLimit, name, v, f64::NAN, "V"))
    }

    /// Check the sensors at loop time `t`; returns a trip event if any limit is violated:
    /// the feedback channel's value and freshness, the sensors' plausible ranges, the rig's
    /// limits, in that order.
    #[inline]
    pub fn check_sensors(&mut self, t: f64, cycle: u64, m: &Measurements) -> Option<Event> {
        if let Some(trip) = self.check_feedback(t, cycle, m) {
            return Some(trip);
        }
        self.check_ranges(t, cycle, m)
            .or_else(|| self.check_limits(t, cycle, m))
    }

    /// The feedback channel is finite and its sample time advanced within
    /// [`SupervisorConfig::stale_timeout`] (s) of loop time `t` (s).
    #[inline]
    fn check_feedback(&mut self, t: f64, cycle: u64, m: &Measurements) -> Option<Event> {
        let c = &self.cfg;
        let (fb, name, unit) = match self.feedback {
            FeedbackChannel::Force => (m.force, "force", "N"),
            FeedbackChannel::Position => (m.position, "position", "m"),
        };
        if !fb.is_finite() {
            return Some(Self::trip(
                t,
                cycle,
                EventKind::SensorNan,
                name,
                fb,
                f64::NAN,
                unit,
            ));
        }
        if m.t.is_nan() || m.t > self.last_sample_t {
            self.last_sample_t = m.t;
            self.last_advance_t = t;
        } else if t - self.last_advance_t > c.stale_timeout {
            return Some(Self::trip(
                t,
                cycle,
                EventKind::SensorStale,
                name,
                t - self.last_advance_t,
                c.stale_timeout,
                "s",
            ));
        }
        None
    }

    /// The sensors' plausible ranges: |force| within `force_range` (N), the chamber pressures
    /// within −1 bar and `pressure_range` (Pa).
    #[inline]
    fn check_ranges(&self, t: f64, cycle: u64, m: &Measurements) -> Option<Event> {
        let c = &self.cfg;
        if let Some(r) = c.force_range {
            if m.force.is_finite() && m.force.abs() > r {
                return Some(Self::trip(
                    t,
                    cycle,
                    EventKind::SensorRange,
                    "force",
                    m.force,
                    r,
                    "N",
                ));
            }
        }
        if let Some(r) = c.pressure_range {
            for (ch, p) in [("p_a", m.p_a), ("p_b", m.p_b)] {
                if p.is_finite() && (p > r || p < -1.0e5) {
                    return Some(Self::trip(t, cycle, EventKind::SensorRange, ch, p, r, "Pa"));
                }
            }
        }
        None
    }

    /// The rig's limits: chamber pressures (Pa), |force| (N), position (m).
    #[inline]
    fn check_limits(&self, t: f64, cycle: u64, m: &Measurements) -> Option<Event> {
        let c = &self.cfg;
        if let Some(lim) = c.max_pressure {
            for (ch, p) in [("p_a", m.p_a), ("p_b", m.p_b)] {
                if p.is_finite() && p > lim {
                    return Some(Self::trip(
                        t,
                        cycle,
                        EventKind::PressureLimit,
                        ch,
                        p,
                        lim,
                        "Pa",
                    ));
                }
            }
        }
        if let Some(lim) = c.max_force {
            if m.force.is_finite() && m.force.abs() > lim {
                return Some(Self::trip(
                    t,
                    cycle,
                    EventKind::ForceLimit,
                    "force",
                    m.force,
                    lim,
                    "N",
                ));
            }
        }
        if let Some(lo) = c.min_position {
            if m.position.is_finite() && m.position < lo {
                return Some(Self::trip(
                    t,
                    cycle,
                    EventKind::PositionLimit,
                    "position",
                    m.position,
                    lo,
                    "m",
                ));
            }
        }
        if let Some(hi) = c.max_position {
            if m.position.is_finite() && m.position > hi {
                return Some(Self::trip(
                    t,
                    cycle,
                    EventKind::PositionLimit,
                    "position",
                    m.position,
                    hi,
                    "m",
                ));
            }
        }
        None
    }

    /// Saturation watch (see [`SupervisorConfig::saturation_window`]): `saturated` says whether
    /// this cycle's command sat at a limit; `dt` is the control period (s).
    #[inline]
    pub fn check_saturation(
        &mut self,
        t: f64,
        cycle: u64,
        saturated: bool,
        dt: f64,
    ) -> Option<Event> {
        let window = self.cfg.saturation_window?;
        let a = (dt / window).min(1.0);
        self.saturated_share += a * (f64::from(u8::from(saturated)) - self.saturated_share);
        (self.saturated_share > self.cfg.max_saturation).then(|| {
            Self::trip(
                t,
                cycle,
                EventKind::Saturation,
                "command",
                self.saturated_share,
                self.cfg.max_saturation,
                "-",
            )
        })
    }

    /// Following-error supervision (see [`SupervisorConfig::following_error`]): `error` is
    /// this cycle's setpoint − feedback (N or m; NaN in open loop, which is not checked),
    /// `dt` the control period (s). Counter-based debouncing (as the AUTOSAR diagnostic event
    /// manager's, AUTOSAR CP SWS DiagnosticEventManager R4.4, "counter-based debounce
    /// algorithm"): the time above the bound counts up, the time below counts down (never
    /// below 0), and the run trips once the count exceeds `following_error_time`. A
    /// continuous excursion trips after exactly that time; an oscillation that spends more
    /// of its period above the bound than below it (a limit cycle around the setpoint, whose
    /// error crosses zero every half period) trips too. The event holds the error and the
    /// bound in the loop's unit. Allocation-free.
    #[inline]
    pub fn check_following(&mut self, t: f64, cycle: u64, error: f64, dt: f64) -> Option<Event> {
        let bound = self.cfg.following_error?;
        if !error.is_finite() {
            return None;
        }
        self.following_over = if error.abs() > bound {
            self.following_over + dt
        } else {
            (self.following_over - dt).max(0.0)
        };
        // Half a period of slack: the count is a sum of periods, whose rounding must not
        // decide the cycle of the trip.
        (self.following_over > self.cfg.following_error_time + 0.5 * dt).then(|| {
            let (channel, unit) = match self.feedback {
                FeedbackChannel::Force => ("force", "N"),
                FeedbackChannel::Position => ("position", "m"),
            };
            Self::trip(
                t,
                cycle,
                EventKind::FollowingError,
                channel,
                error,
                bound,
                unit,
            )
        })
    }

    /// Limit the command; returns the command to apply and a warning the first time it clamps.
    /// A non-finite command is a trip.
    #[inline]
    pub fn limit_command(&mut self, t: f64, cycle: u64, u: f64) -> (f64, Option<Event>) {
        if !u.is_finite() {
            return (
                self.cfg.safe_command,
                Some(Self::trip(
                    t,
                    cycle,
                    EventKind::CommandLimit,
                    "command",
                    u,
                    f64::NAN,
                    "V",
                )),
            );
        }
        match self.cfg.max_command {
            Some(m) if u.abs() > m => {
                let ev = if self.command_clamped_reported {
                    None
                } else {
                    self.command_clamped_reported = true;
                    Some(Event {
                        t,
                        cycle,
                        severity: Severity::Warning,
                        kind: EventKind::CommandLimit,
                        channel: "command",
                        value: u,
                        limit: m,
                        unit: "V",
                    })
                };
                (clamp_command(u, m), ev)
            }
            _ => (u, None),
        }
    }
}

/// Command `u` (V) limited to ±`max_command` (V; `f64::INFINITY`: no limit): the clamp of
/// [`Supervisor::limit_command`], which the diagnosis's closed-loop replay applies too.
#[inline]
pub fn clamp_command(u: f64, max_command: f64) -> f64 {
    if u.abs() > max_command {
        u.clamp(-max_command, max_command)
    } else {
        u
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn following(bound: Option<f64>, time: f64) -> Supervisor {
        let cfg = SupervisorConfig {
            following_error: bound,
            following_error_time: time,
            ..SupervisorConfig::default()
        };
        Supervisor::new(&cfg, FeedbackChannel::Force)
    }

    /// Cycles until the first trip of `sup` fed `error(k)` at period `dt` (None: no trip in `n`).
    fn first_trip(
        sup: &mut Supervisor,
        dt: f64,
        n: u64,
        error: impl Fn(u64) -> f64,
    ) -> Option<(u64, Event)> {
        (0..n).find_map(|k| {
            sup.check_following(k as f64 * dt, k, error(k), dt)
                .map(|e| (k, e))
        })
    }

    /// A constant excursion trips on the first cycle whose accumulated time exceeds the
    /// bound's time: 0.1 s at 1 ms is 100 cycles at the limit, the 101st over it (cycle 100);
    /// the event carries the error, the bound and the loop's unit.
    #[test]
    fn a_steady_excursion_trips_after_the_time() {
        let mut sup = following(Some(10.0), 0.1);
        let (k, ev) = first_trip(&mut sup, 1e-3, 1000, |_| -25.0).expect("a trip");
        assert_eq!(k, 100);
        assert_eq!(ev.kind, EventKind::FollowingError);
        assert_eq!(
            (ev.channel, ev.value, ev.limit, ev.unit),
            ("force", -25.0, 10.0, "N")
        );
        assert_eq!(ev.severity, Severity::Trip);
        // At or below the bound, never.
        let mut sup = following(Some(10.0), 0.1);
        assert!(first_trip(&mut sup, 1e-3, 10_000, |_| 10.0).is_none());
    }

    /// Counter-based debounce: an error above the bound 3 cycles in 4 gains 2 periods per 4
    /// cycles, so the count passes 0.1 s after 50 periods of gain, near cycle 200; one above
    /// the bound 1 cycle in 2 (a symmetric excursion) never accumulates.
    #[test]
    fn an_oscillation_mostly_above_the_bound_trips_a_balanced_one_does_not() {
        let mut sup = following(Some(1.0), 0.1);
        let (k, _) = first_trip(
            &mut sup,
            1e-3,
            10_000,
            |k| if k % 4 == 3 { 0.0 } else { 5.0 },
        )
        .expect("a trip");
        assert!((195..=205).contains(&k), "{k}");
        let mut sup = following(Some(1.0), 0.1);
        assert!(first_trip(&mut sup, 1e-3, 10_000, |k| if k % 2 == 0 {
            5.0
        } else {
            0.5
        })
        .is_none());
    }

    /// No bound or no error (open loop: NaN) is no check.
    #[test]
    fn no_bound_or_no_error_is_not_checked() {
        let mut sup = following(None, 0.1);
        assert!(first_trip(&mut sup, 1e-3, 1000, |_| 1e9).is_none());
        let mut sup = following(Some(1.0), 0.1);
        assert!(first_trip(&mut sup, 1e-3, 1000, |_| f64::NAN).is_none());
    }
}
