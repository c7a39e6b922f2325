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
}

impl SupervisorConfig {
    fn default_stale() -> f64 {
        0.05
    }
    fn default_max_saturation() -> f64 {
        0.9
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

    /// Check the sensors at loop time `t`; returns a trip event if any limit is violated.
    #[inline]
    pub fn check_sensors(&mut self, t: f64, cycle: u64, m: &Measurements) -> Option<Event> {
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
