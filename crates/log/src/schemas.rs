//! JSON Schemas (draft 2020-12 subset that Foxglove reads: `type`, `properties`,
//! `description`, `enum`, `items`) of the JSON channels of an ehactl log: `/events`,
//! `/summary`, the envelope of `/config`, and `foxglove.Log` for `/log` (the events again,
//! in Foxglove's own Log schema so that they appear in its Log panel). The same schemas are
//! used by the MCAP log and by the live view (`ehactl run --live`).

use crate::record::{Event, Severity};
use serde_json::{json, Value};

/// Schema name of `/events`.
pub const EVENT_SCHEMA_NAME: &str = "ehactl.Event";
/// Schema name of `/summary`.
pub const SUMMARY_SCHEMA_NAME: &str = "ehactl.Summary";
/// Schema name of `/config`.
pub const CONFIG_SCHEMA_NAME: &str = "ehactl.Config";
/// Schema name of `/log` (Foxglove's well-known log message).
pub const FOXGLOVE_LOG_SCHEMA_NAME: &str = "foxglove.Log";

fn num(d: &str) -> Value {
    json!({"type": "number", "description": d})
}
fn int(d: &str) -> Value {
    json!({"type": "integer", "description": d})
}
fn text(d: &str) -> Value {
    json!({"type": "string", "description": d})
}
fn nullable_num(d: &str) -> Value {
    json!({"type": ["number", "null"], "description": d})
}

/// Schema of one `/events` message ([`Event::to_json`]).
pub fn event_schema() -> Value {
    json!({
        "title": EVENT_SCHEMA_NAME,
        "description": "Run event: start, warning, trip, parameter change, end",
        "type": "object",
        "properties": {
            "t": num("time from the start of the run (s)"),
            "cycle": int("control cycle index"),
            "severity": {"type": "string", "enum": ["info", "warning", "trip"], "description": "severity"},
            "kind": text("event kind, e.g. start, pressure_limit, hal_fault, param_change, end"),
            "channel": text("channel or quantity concerned"),
            "value": nullable_num("observed value (SI, unit in `unit`); null if none"),
            "limit": nullable_num("limit that was crossed (SI, unit in `unit`); null if none"),
            "unit": text("unit of value and limit"),
            "text": text("one-line description"),
            "request": text("param_refused only: the refused request line, as received"),
            "reason": text("param_refused only: why it was refused"),
        },
        "required": ["t", "cycle", "severity", "kind", "text"],
    })
}

/// Schema of the `/summary` message (the `ehactl run --json` object plus logger counters).
/// Backend- and wall-clock-specific fields (jitter, bus load, …) are additional properties.
pub fn summary_schema() -> Value {
    json!({
        "title": SUMMARY_SCHEMA_NAME,
        "description": "Summary of a run (same object as `ehactl run --json`)",
        "type": "object",
        "properties": {
            "cycles": int("control cycles run"),
            "control_rate_hz": num("control rate (Hz)"),
            "duration_s": num("simulated / run time (s)"),
            "rms_error": nullable_num("RMS tracking error (unit in error_unit); null in open loop"),
            "rms_error_settled": nullable_num("RMS tracking error after the setpoint's dynamics start"),
            "max_abs_error": nullable_num("largest |error| (unit in error_unit)"),
            "error_unit": text("unit of the controlled variable: N, m, or V (open loop)"),
            "mcap": {"type": ["string", "null"], "description": "path of the MCAP log"},
            "trip": {"type": ["string", "null"], "description": "null, or the reason of the supervisor trip"},
            "trip_kind": {"type": ["string", "null"], "description": "kind of the trip event"},
            "interrupted": {"type": "boolean", "description": "stopped by SIGINT / SIGTERM"},
            "sim_speed_x_realtime": num("run time / wall time"),
            "wall_time_s": num("wall-clock time of the loop (s)"),
            "substeps": int("plant substeps per control period (0 on hardware)"),
            "realtime": {"type": "boolean", "description": "paced by the wall clock"},
            "jitter_p99_us": nullable_num("wall-clock runs: 99th percentile of the wake-up lateness, cycle start − its deadline (µs); also _p50_us, _p999_us, _max_us"),
            "exec_p99_us": nullable_num("wall-clock runs: 99th percentile of the execution time, wall clock, cycle start → next wait (µs); also _p50_us, _p999_us, _max_us"),
            "exec_cpu_p99_us": nullable_num("wall-clock runs: 99th percentile of the loop thread's CPU time per cycle, cycle start → next wait, preemptions excluded (µs); also _p50_us, _p999_us, _max_us"),
            "exec_cpu_clamped": int("wall-clock runs: cycles whose thread CPU time read above their wall execution time (scheduler clocks of the cores not synchronised) and was taken as the wall time"),
            "overruns": int("wall-clock runs: cycles that ended after the next deadline"),
            "overruns_exec": int("wall-clock runs: overruns whose cycle's own CPU time alone exceeded the period (our cycle took too long)"),
            "overruns_wakeup": int("wall-clock runs: overruns of cycles whose work fit in the period but whose thread was not running when needed (started late or preempted inside the cycle)"),
            "records_written": int("cycle records written to the log"),
            "log_decimation": int("one cycle in N written to the log (events, first and last cycle always)"),
            "log": {"type": ["object", "null"], "description": "logger counters", "properties": {
                "records_written": int("cycle records written"),
                "records_dropped": int("cycle records dropped (queue full, wall-clock runs)"),
                "pushes_waited": int("pushes that waited for room (simulated time)"),
                "events_written": int("events written"),
                "queue_high_water": int("highest queue occupancy (records)"),
                "queue_capacity": int("queue capacity (records)"),
                "can_frames_written": int("raw CAN frames written to /can"),
                "can_frames_dropped": int("raw CAN frames dropped"),
            }},
        },
        "additionalProperties": true,
    })
}

/// Schema of the `/config` message: the envelope `{toml, config, backend}`; `config_schema`
/// describes the `config` object (built from the parameter registries by the controller).
pub fn config_schema(config_schema: Value) -> Value {
    json!({
        "title": CONFIG_SCHEMA_NAME,
        "description": "The rig config as run (defaults filled in)",
        "type": "object",
        "properties": {
            "toml": text("the config as TOML text"),
            "config": config_schema,
            "backend": text("backend: sim or canopen"),
        },
    })
}

/// Foxglove's `foxglove.Log` message as a JSON Schema (fields and level values as published
/// in Foxglove's schema reference: timestamp {sec, nsec}, level 0 UNKNOWN … 5 FATAL,
/// message, name, file, line).
pub fn foxglove_log_schema() -> Value {
    json!({
        "title": FOXGLOVE_LOG_SCHEMA_NAME,
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": {"type": "object", "title": "time", "description": "Timestamp of log message",
                "properties": {"sec": {"type": "integer", "minimum": 0},
                               "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
            "level": {"title": "foxglove.LogLevel", "description": "Log level",
                "oneOf": [
                    {"title": "UNKNOWN", "const": 0}, {"title": "DEBUG", "const": 1},
                    {"title": "INFO", "const": 2}, {"title": "WARNING", "const": 3},
                    {"title": "ERROR", "const": 4}, {"title": "FATAL", "const": 5}]},
            "message": {"type": "string", "description": "Log message"},
            "name": {"type": "string", "description": "Process or node name"},
            "file": {"type": "string", "description": "Filename"},
            "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        },
    })
}

/// `ev` as a `foxglove.Log` message (JSON): info → INFO (2), warning → WARNING (3),
/// trip → ERROR (4); name `ehactl/<kind>`; timestamp = run time (s) as sec/nsec.
pub fn event_to_foxglove_log(ev: &Event) -> Value {
    let t = ev.t.max(0.0);
    let sec = t.floor();
    let nsec = ((t - sec) * 1e9).round().min(999_999_999.0);
    json!({
        "timestamp": {"sec": sec as u64, "nsec": nsec as u64},
        "level": match ev.severity {
            Severity::Info => 2,
            Severity::Warning => 3,
            Severity::Trip => 4,
        },
        "message": ev.describe(),
        "name": format!("ehactl/{}", ev.kind.as_str()),
        "file": "",
        "line": 0,
    })
}
