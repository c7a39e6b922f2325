//! Fixed-size per-cycle records and events (copper-rs style: preallocated, serialised after
//! the cycle by the logger thread), with their ROS 2 message schemas and CDR encoding so
//! Foxglove plots every field directly.

use crate::{Measurements, PlantState};

/// Everything that happened in one control cycle.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleRecord {
    /// Cycle index from 0.
    pub cycle: u64,
    /// Cycle time (s).
    pub t: f64,
    /// Setpoint (N or m).
    pub setpoint: f64,
    /// Setpoint rate (N/s or m/s).
    pub setpoint_rate: f64,
    /// Feedback used by the controller (N or m).
    pub feedback: f64,
    /// Error setpoint − feedback (N or m).
    pub error: f64,
    /// Command sent to the valve (V).
    pub command: f64,
    /// Command before limits (V).
    pub command_unsat: f64,
    /// Proportional term (V).
    pub p_term: f64,
    /// Integral term (V).
    pub i_term: f64,
    /// Derivative term (V).
    pub d_term: f64,
    /// Feed-forward term (V).
    pub ff_term: f64,
    /// Sensor readings.
    pub meas: Measurements,
    /// Ground-truth plant state (simulation only; `has_plant` says whether it is valid).
    pub plant: PlantState,
    /// Whether `plant` is valid.
    pub has_plant: bool,
    /// Wall-clock timing of the cycle (wall-clock pacers only; logged on `/timing`).
    pub timing: Option<CycleTiming>,
}

/// Wall-clock timing of one cycle, measured by a real-time pacer on CLOCK_MONOTONIC.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleTiming {
    /// Start of the cycle since the first deadline of the run (s, wall clock).
    pub wall_t: f64,
    /// Wake-up lateness: actual start − deadline (µs, ≥ 0).
    pub lateness_us: f64,
    /// Time since the previous cycle's start (µs); NaN for the first cycle.
    pub period_us: f64,
    /// Execution time of the previous cycle, from its start to the next wait (µs).
    pub exec_prev_us: f64,
    /// Deadlines skipped before this cycle by the overrun policy (-).
    pub skipped: u32,
    /// Whether the previous cycle overran (finished after this cycle's deadline).
    pub overrun: bool,
    /// Whether that overrun was the previous cycle's own doing: its execution
    /// (`exec_prev_us`) alone exceeded the period. False for an overrun of a cycle that fit
    /// in the period but started late (the thread was not running at its deadline).
    pub overrun_exec: bool,
}

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
    /// The valve was given its safe command at the end of the run.
    SafeStop,
    /// Something on the CAN bus worth recording (malformed or unexpected frame, EMCY, device
    /// state); the backend decides whether it also trips (then a `hal_fault` follows).
    CanBus,
    /// The MCAP writer failed (disk full, I/O error): the run stops at once.
    LogFailed,
    /// The command sat at a limit for too much of the supervisor's saturation window.
    Saturation,
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
            EventKind::SafeStop => "safe_stop",
            EventKind::CanBus => "can_bus",
            EventKind::LogFailed => "log_failed",
            EventKind::Saturation => "saturation",
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
    /// One-line human description.
    pub fn describe(&self) -> String {
        let mut s = format!(
            "{} {} on {} at t = {:.6} s (cycle {})",
            self.severity.as_str(),
            self.kind.as_str(),
            self.channel,
            self.t,
            self.cycle
        );
        if self.value.is_finite() || self.value.is_nan() && self.kind == EventKind::SensorNan {
            s.push_str(&format!(": value {} {}", self.value, self.unit));
        }
        if self.limit.is_finite() {
            s.push_str(&format!(", limit {} {}", self.limit, self.unit));
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

/// Field names of the `/control` message after `cycle` (all float64), in order.
pub const CONTROL_FIELDS: [&str; 16] = [
    "t",
    "setpoint",
    "setpoint_rate",
    "feedback",
    "error",
    "command",
    "command_unsat",
    "p_term",
    "i_term",
    "d_term",
    "ff_term",
    "force",
    "position",
    "p_a",
    "p_b",
    "spool",
];

/// Field names of the `/plant` message before `stuck` (all float64), in order.
pub const PLANT_FIELDS: [&str; 16] = [
    "t",
    "command",
    "spool",
    "spool_velocity",
    "p_a",
    "p_b",
    "p_s",
    "x",
    "v",
    "x_load",
    "v_load",
    "q_a",
    "q_b",
    "friction",
    "external",
    "rod_force",
];

/// ros2msg schema text of `/control`.
pub fn control_schema() -> String {
    let mut s = String::from(
        "# One control cycle of ehactl (SI units: s, N or m, V, Pa; spool as fraction of travel)\nuint64 cycle\n",
    );
    for f in CONTROL_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s
}

/// ros2msg schema text of `/plant`.
pub fn plant_schema() -> String {
    let mut s = String::from("# Ground-truth plant state of the ehactl simulation (SI units)\n");
    for f in PLANT_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s.push_str("bool stuck\n");
    s
}

/// Field names of the `/timing` message after `cycle` and `t` (all float64), in order;
/// then `uint32 skipped`, `bool overrun` and `bool overrun_exec` (appended in issue 16;
/// readers of the older layout, which ends at `overrun`, still read a prefix).
pub const TIMING_FIELDS: [&str; 4] = ["wall_t", "lateness_us", "period_us", "exec_prev_us"];

/// ros2msg schema text of `/timing`.
pub fn timing_schema() -> String {
    let mut s = String::from(
        "# Wall-clock timing of one ehactl cycle (CLOCK_MONOTONIC; wall_t in s, the rest in us)\nuint64 cycle\nfloat64 t\n",
    );
    for f in TIMING_FIELDS {
        s.push_str("float64 ");
        s.push_str(f);
        s.push('\n');
    }
    s.push_str("uint32 skipped\nbool overrun\nbool overrun_exec\n");
    s
}

/// CDR little-endian encapsulation header.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

impl CycleRecord {
    /// Values of the `/control` message in [`CONTROL_FIELDS`] order.
    pub fn control_values(&self) -> [f64; 16] {
        let m = &self.meas;
        [
            self.t,
            self.setpoint,
            self.setpoint_rate,
            self.feedback,
            self.error,
            self.command,
            self.command_unsat,
            self.p_term,
            self.i_term,
            self.d_term,
            self.ff_term,
            m.force,
            m.position,
            m.p_a,
            m.p_b,
            m.spool,
        ]
    }

    /// Values of the `/plant` message in [`PLANT_FIELDS`] order.
    pub fn plant_values(&self) -> [f64; 16] {
        let p = &self.plant;
        [
            p.t,
            p.command,
            p.spool,
            p.spool_velocity,
            p.p_a,
            p.p_b,
            p.p_s,
            p.x,
            p.v,
            p.x_load,
            p.v_load,
            p.q_a,
            p.q_b,
            p.friction,
            p.external,
            p.rod_force,
        ]
    }

    /// CDR encoding of `/control` into `buf` (cleared first).
    pub fn encode_control(&self, buf: &mut Vec<u8>) {
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        buf.extend_from_slice(&self.cycle.to_le_bytes());
        for v in self.control_values() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// CDR encoding of `/timing` into `buf` (cleared first); false if the record has no
    /// timing. Layout: cycle u64, t and [`TIMING_FIELDS`] f64, skipped u32, overrun u8,
    /// overrun_exec u8 (every field naturally aligned, so no padding).
    pub fn encode_timing(&self, buf: &mut Vec<u8>) -> bool {
        let Some(tm) = self.timing else {
            return false;
        };
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        buf.extend_from_slice(&self.cycle.to_le_bytes());
        for v in [
            self.t,
            tm.wall_t,
            tm.lateness_us,
            tm.period_us,
            tm.exec_prev_us,
        ] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(&tm.skipped.to_le_bytes());
        buf.push(tm.overrun as u8);
        buf.push(tm.overrun_exec as u8);
        true
    }

    /// CDR encoding of `/plant` into `buf` (cleared first).
    pub fn encode_plant(&self, buf: &mut Vec<u8>) {
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        for v in self.plant_values() {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.push(self.plant.stuck as u8);
    }
}
