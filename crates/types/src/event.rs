//! Events: fixed-size, `Copy` reports of what happened in a cycle (limits, trips, faults,
//! run start and end), raised by the supervisor, the pacer and the backends and written by
//! the logger (crates/log/src/record.rs encodes them, crates/log/src/schemas.rs names their
//! channel).

// A pressure of 2.1e300 Pa reads `2.1e300`, not 301 digits.
use crate::spec::readable;

/// What an event reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    /// Run started.
    Start,
    /// Pressure limit exceeded.
    PressureLimit,
    /// Position limit exceeded.
    PositionLimit,
    /// Force limit exceeded.
    ForceLimit,
    /// Command limit exceeded (controller output clamped by the supervisor).
    CommandLimit,
    /// A sensor read NaN.
    SensorNan,
    /// A sensor read outside its plausible range.
    SensorRange,
    /// A sensor stopped updating.
    SensorStale,
    /// The backend failed.
    HalFault,
    /// Stop requested by a signal (SIGINT / SIGTERM).
    Signal,
    /// Run completed its duration.
    End,
    /// A cycle finished after the next deadline (wall-clock pacer).
    Overrun,
    /// Real-time set-up (SCHED_FIFO, mlockall, CPU affinity) could not be applied.
    RtSetup,
    /// A live parameter change took effect at a cycle boundary.
    ParamChange,
    /// A live parameter change (`ehactl set`) was refused; nothing changed.
    ParamRefused,
    /// The valve was given its safe command at the end of the run.
    SafeStop,
    /// Something on the CAN bus worth recording (malformed or unexpected frame, EMCY, device
    /// state); the backend decides whether it also trips (then a `hal_fault` follows).
    CanBus,
    /// The MCAP writer failed (disk full, I/O error): the run stops at once.
    LogFailed,
    /// The command sat at a limit for too much of the supervisor's saturation window.
    Saturation,
    /// |setpoint − feedback| stayed above the supervisor's following-error bound for longer
    /// than its time (a loop that does not follow: unstable, stuck, or mis-tuned).
    FollowingError,
    /// The simulated plant reached a state no rig can have (a pressure far beyond the
    /// supply, a velocity or force far beyond what the cylinder can produce): a simulation
    /// fault, not a tracking figure.
    PlantImplausible,
    /// The linearised loop of the config is unstable (a closed-loop pole on or outside the
    /// unit circle), warned at the start of a run.
    UnstableLoop,
}

impl EventKind {
    /// Stable name used in logs and summaries.
    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Start => "start",
            EventKind::PressureLimit => "pressure_limit",
            EventKind::PositionLimit => "position_limit",
            EventKind::ForceLimit => "force_limit",
            EventKind::CommandLimit => "command_limit",
            EventKind::SensorNan => "sensor_nan",
            EventKind::SensorRange => "sensor_range",
            EventKind::SensorStale => "sensor_stale",
            EventKind::HalFault => "hal_fault",
            EventKind::Signal => "signal",
            EventKind::End => "end",
            EventKind::Overrun => "overrun",
            EventKind::RtSetup => "rt_setup",
            EventKind::ParamChange => "param_change",
            EventKind::ParamRefused => "param_refused",
            EventKind::SafeStop => "safe_stop",
            EventKind::CanBus => "can_bus",
            EventKind::LogFailed => "log_failed",
            EventKind::Saturation => "saturation",
            EventKind::FollowingError => "following_error",
            EventKind::PlantImplausible => "plant_implausible",
            EventKind::UnstableLoop => "unstable_loop",
        }
    }
}

/// Severity of an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Severity {
    /// Informational.
    Info,
    /// Warning, run continues.
    Warning,
    /// Trip: the valve went to its safe command and the run ended.
    Trip,
}

impl Severity {
    /// Name.
    pub fn as_str(self) -> &'static str {
        match self {
            Severity::Info => "info",
            Severity::Warning => "warning",
            Severity::Trip => "trip",
        }
    }
}

/// A fixed-size event; its text is produced by the logger thread, not in the cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Event {
    /// Time (s).
    pub t: f64,
    /// Cycle index.
    pub cycle: u64,
    /// Severity.
    pub severity: Severity,
    /// Kind.
    pub kind: EventKind,
    /// Channel or quantity concerned (static text).
    pub channel: &'static str,
    /// Observed value (SI).
    pub value: f64,
    /// Limit that was crossed (SI), NaN if none.
    pub limit: f64,
    /// Unit of value and limit.
    pub unit: &'static str,
}

impl Event {
    /// An event that carries no value: value and limit NaN, no unit.
    pub fn note(
        t: f64,
        cycle: u64,
        severity: Severity,
        kind: EventKind,
        channel: &'static str,
    ) -> Self {
        Event {
            t,
            cycle,
            severity,
            kind,
            channel,
            value: f64::NAN,
            limit: f64::NAN,
            unit: "",
        }
    }

    /// One-line human description (values in the event's SI unit).
    pub fn describe(&self) -> String {
        let mut s = format!(
            "{} {} on {} at t = {:.6} s (cycle {})",
            self.severity.as_str(),
            self.kind.as_str(),
            self.channel,
            self.t,
            self.cycle
        );
        // An infinite value is what tripped (a non-finite term); only a NaN without meaning
        // (no sensor reading) is left out.
        if !self.value.is_nan() || self.kind == EventKind::SensorNan {
            s.push_str(&format!(": value {} {}", readable(self.value), self.unit));
        }
        if self.limit.is_finite() {
            s.push_str(&format!(", limit {} {}", readable(self.limit), self.unit));
        }
        s
    }

    /// JSON form for the `/events` channel.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "t": self.t,
            "cycle": self.cycle,
            "severity": self.severity.as_str(),
            "kind": self.kind.as_str(),
            "channel": self.channel,
            "value": if self.value.is_finite() { serde_json::json!(self.value) } else { serde_json::Value::Null },
            "limit": if self.limit.is_finite() { serde_json::json!(self.limit) } else { serde_json::Value::Null },
            "unit": self.unit,
            "text": self.describe(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trip(value: f64) -> String {
        Event {
            value,
            limit: 25e6,
            unit: "Pa",
            ..Event::note(0.0, 0, Severity::Trip, EventKind::PressureLimit, "p_a")
        }
        .describe()
    }

    /// A runaway value reads as a number a person can read; an infinite one is shown (it is
    /// what tripped), the limit keeps its plain form.
    #[test]
    fn values_stay_readable() {
        let huge = trip(2.1e300);
        assert!(huge.contains("value 2.1e300 Pa"), "{huge}");
        assert!(huge.len() < 140, "{huge}");
        assert!(trip(f64::INFINITY).contains("value inf Pa"));
        assert!(trip(3.0e7).contains("value 30000000 Pa, limit 25000000 Pa"));
        assert!(!trip(f64::NAN).contains("value"));
    }
}
