//! # ehactl-config
//!
//! Rig configuration: the plant sections of `ehactl-plant` plus control, setpoint,
//! supervisor, run, log, realtime and CANopen sections. Loading validates every field against the parameter
//! registries and reports the first problem with its dotted path and expected unit.

use ehactl_control::controller::Controller;
use ehactl_control::pd::{Pd, PdGains};
use ehactl_control::pi::{Pi, PiGains};
use ehactl_control::setpoint::{SetpointConfig, SetpointKind, Sweep};
use ehactl_control::supervisor::SupervisorConfig;
use ehactl_params_derive::Params;
use ehactl_plant::spec::{self, ConfigError, Param};
use ehactl_plant::PlantParams;
use ehactl_types::canopen::{canopen_params, CanopenConfig};
use ehactl_types::Timebase;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::LazyLock;

pub mod envelope;
pub mod inputs;
pub mod tree;

/// Controlled variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ControlMode {
    /// PI on the load-cell force (004).
    Force,
    /// PD on the piston position (003).
    Position,
    /// No feedback: the setpoint (V) goes straight to the valve (open-loop tests).
    OpenLoop,
}

impl ControlMode {
    /// Unit of the reference and the controlled variable: N (force), m (position), V (open
    /// loop: the valve command).
    pub fn unit(self) -> &'static str {
        match self {
            ControlMode::Force => "N",
            ControlMode::Position => "m",
            ControlMode::OpenLoop => "V",
        }
    }
}

/// PI section `[control.pi]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct PiConfig {
    /// K_P (V/V of scaled error).
    #[param(
        unit = "V/V",
        range = Within(0.0, 1.0e3),
        desc = "PI proportional gain K_P (004: 0.57)"
    )]
    pub kp: f64,
    /// I = 1/T_i (1/s).
    #[param(
        unit = "1/s",
        range = Within(0.0, 1.0e9),
        desc = "PI integral rate I (004: 386.24)"
    )]
    pub integral: f64,
    /// Error scale (V/N); 004: load-cell sensitivity 0.5097e-3.
    #[param(
        unit = "V/N",
        range = Positive,
        desc = "error scale, load-cell sensitivity (004: 0.5097e-3)"
    )]
    pub error_scale: f64,
    /// Lower output limit (V).
    #[serde(default = "neg_ten")]
    #[param(unit = "V", range = Finite, desc = "lower command limit")]
    pub u_min: f64,
    /// Upper output limit (V).
    #[serde(default = "ten")]
    #[param(unit = "V", range = Finite, desc = "upper command limit")]
    pub u_max: f64,
    /// Back-calculation gain (1/s); 0 = clamping anti-windup.
    #[serde(default)]
    #[param(
        unit = "1/s",
        range = Within(0.0, 1.0e9),
        desc = "back-calculation anti-windup gain"
    )]
    pub tracking: f64,
    /// Setpoint feed-forward (V/N): u_ff = feedforward · setpoint. Bounded to ±1 V/N, which
    /// already puts the full ±10 V valve range on a 10 N setpoint; the shipped rigs' force
    /// setpoints are 10²–10⁵ N, so a useful feed-forward is below 10⁻² V/N. (Unbounded, a
    /// value such as 1.7e308 made the term infinite and pinned the command at a limit.)
    #[serde(default)]
    #[param(
        unit = "V/N",
        range = Within(-1.0, 1.0),
        desc = "setpoint feed-forward"
    )]
    pub feedforward: f64,
}

/// PD section `[control.pd]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct PdConfig {
    /// K_P (V/m).
    #[param(
        unit = "V/m",
        range = Within(0.0, 1.0e7),
        desc = "PD proportional gain K_P (003 eq. 32)"
    )]
    pub kp: f64,
    /// T_D (s).
    #[serde(default)]
    #[param(
        unit = "s",
        range = Within(0.0, 1.0e3),
        desc = "derivative time T_D (003 eq. 32)"
    )]
    pub td: f64,
    /// Derivative filter ratio N (-); 0 = unfiltered (003 eq. 32).
    #[serde(default)]
    #[param(
        unit = "-",
        range = Within(0.0, 1.0e3),
        desc = "derivative filter ratio N"
    )]
    pub filter_n: f64,
    /// Output limit (V), symmetric.
    #[serde(default = "ten")]
    #[param(unit = "V", range = Positive, desc = "command limit")]
    pub u_max: f64,
    /// Velocity feed-forward (V·s/m): u_ff = feedforward_velocity · ṙ. Bounded to ±10⁴
    /// V·s/m, the full ±10 V valve range at a setpoint rate of 1 mm/s.
    #[serde(default)]
    #[param(
        unit = "V·s/m",
        range = Within(-1.0e4, 1.0e4),
        desc = "velocity feed-forward"
    )]
    pub feedforward_velocity: f64,
}

fn ten() -> f64 {
    10.0
}
fn neg_ten() -> f64 {
    -10.0
}

/// `[control]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    /// Controlled variable.
    #[param(
        choice,
        desc = "controlled variable: force (PI on the load cell, 004), position (PD on the piston, 003) or open_loop (setpoint in V straight to the valve)"
    )]
    pub mode: ControlMode,
    /// PI gains (force mode).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub pi: Option<PiConfig>,
    /// PD gains (position mode).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[param(nested)]
    pub pd: Option<PdConfig>,
}

/// Longest run (s): the upper end of `run.duration`'s range, and the cap of every duration
/// override (`ehactl run --duration`, `ehactl.run(duration=…)`). 10⁶ s is 11.6 days; at the
/// 5 kHz of the Sahu 2022 rig that is 5·10⁹ cycles.
pub const MAX_DURATION_S: f64 = 1.0e6;

/// `[run]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Duration (s).
    #[param(unit = "s", range = Within(1e-6, 1.0e6), desc = "run duration")]
    pub duration: f64,
    /// Control rate (Hz); 004: 5 kHz.
    #[serde(default = "RunConfig::default_rate")]
    #[param(
        unit = "Hz",
        range = Within(1.0, 1.0e6),
        desc = "control rate (004: 5000)"
    )]
    pub control_rate_hz: f64,
}

impl RunConfig {
    fn default_rate() -> f64 {
        5000.0
    }
}

/// MCAP chunk compression.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Compression {
    /// None.
    None,
    /// LZ4.
    #[default]
    Lz4,
}

/// `[log]`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct LogConfig {
    /// Chunk compression.
    #[serde(default)]
    #[param(choice, desc = "MCAP chunk compression: lz4 (default) or none")]
    pub compression: Compression,
    /// Record queue capacity (records).
    #[serde(default = "LogConfig::default_queue")]
    #[param(
        unit = "records",
        range = Within(16.0, 1.0e8),
        desc = "logger queue capacity"
    )]
    pub queue_capacity: u64,
    /// Longest span of records held in an open MCAP chunk before it is closed and flushed
    /// (s); with a simulated plant the loop also never runs more than this far ahead of the
    /// file. Bounds what a SIGKILL or power loss can lose (`ehactl recover` rebuilds the rest).
    #[serde(default = "LogConfig::default_chunk_interval")]
    #[param(
        unit = "s",
        range = Within(1e-3, 10.0),
        desc = "longest span of records in an open MCAP chunk (bounds the loss on SIGKILL)"
    )]
    pub chunk_interval: f64,
}

impl LogConfig {
    fn default_queue() -> u64 {
        65_536
    }
    fn default_chunk_interval() -> f64 {
        0.1
    }
}

impl Default for LogConfig {
    fn default() -> Self {
        Self {
            compression: Compression::default(),
            queue_capacity: Self::default_queue(),
            chunk_interval: Self::default_chunk_interval(),
        }
    }
}

/// What the wall-clock executor does after a cycle overran its period.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum OverrunPolicyConfig {
    /// Run the late cycle at once; the deadline grid shifts to it.
    Continue,
    /// Keep the grid; wait for the next deadline still ahead (missed ones are skipped).
    #[default]
    Skip,
    /// As `skip`, and trip (safe command) after `trip_after` consecutive overruns.
    Trip,
}

/// `[realtime]`: settings of the wall-clock executor (`ehactl run --realtime`). Each one
/// that the OS refuses (no CAP_SYS_NICE, RLIMIT_MEMLOCK, …) is a warning, not a failure.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Params)]
#[serde(deny_unknown_fields)]
pub struct RealtimeConfig {
    /// SCHED_FIFO priority of the loop thread (1–99); 0 = keep the normal scheduler.
    #[serde(default = "RealtimeConfig::default_priority")]
    #[param(
        unit = "-",
        range = Within(0.0, 99.0),
        desc = "SCHED_FIFO priority of the loop with --realtime (0 = normal scheduler)"
    )]
    pub priority: u32,
    /// CPU (0-based) to pin the loop thread to; -1 = no pinning.
    #[serde(default = "RealtimeConfig::default_cpu")]
    #[param(
        unit = "-",
        range = Within(-1.0, 4095.0),
        desc = "CPU to pin the loop to with --realtime (-1 = none)"
    )]
    pub cpu: i64,
    /// Lock all memory (mlockall) so that no page fault lands in a cycle.
    #[serde(default = "RealtimeConfig::default_lock")]
    #[param(
        unit = "bool",
        range = Finite,
        desc = "lock all memory (mlockall) with --realtime so no page fault lands in a cycle; true (default) or false"
    )]
    pub lock_memory: bool,
    /// Busy-wait tail before each deadline (s); 0 = sleep only. Must be below the period.
    #[serde(default = "RealtimeConfig::default_spin")]
    #[param(
        unit = "s",
        range = Within(0.0, 1.0),
        desc = "busy-wait tail before each deadline (< period)"
    )]
    pub spin: f64,
    /// Overrun policy: "continue", "skip" or "trip".
    #[serde(default)]
    #[param(
        choice,
        desc = "after an overrun with --realtime: continue (grid shifts), skip (default: keep the grid) or trip (after trip_after)"
    )]
    pub overrun_policy: OverrunPolicyConfig,
    /// Consecutive overruns that trip the run under `overrun_policy = "trip"` (cycles).
    #[serde(default = "RealtimeConfig::default_trip_after")]
    #[param(
        unit = "cycles",
        range = Within(1.0, 1.0e9),
        desc = "consecutive overruns that trip (overrun_policy = \"trip\"; also: continue | skip)"
    )]
    pub trip_after: u32,
}

impl RealtimeConfig {
    fn default_priority() -> u32 {
        80
    }
    fn default_cpu() -> i64 {
        -1
    }
    fn default_lock() -> bool {
        true
    }
    fn default_spin() -> f64 {
        20e-6
    }
    fn default_trip_after() -> u32 {
        3
    }
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        Self {
            priority: Self::default_priority(),
            cpu: Self::default_cpu(),
            lock_memory: Self::default_lock(),
            spin: Self::default_spin(),
            overrun_policy: OverrunPolicyConfig::default(),
            trip_after: Self::default_trip_after(),
        }
    }
}

/// `[rig]`: description only.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct RigInfo {
    /// Short name.
    #[serde(default)]
    pub name: String,
    /// Free text: what rig, which seed.
    #[serde(default)]
    pub description: String,
}

/// A complete rig config.
#[derive(Debug, Clone, PartialEq)]
pub struct RigConfig {
    /// Description.
    pub rig: RigInfo,
    /// Plant.
    pub plant: PlantParams,
    /// Control law.
    pub control: ControlConfig,
    /// Setpoint.
    pub setpoint: SetpointConfig,
    /// Supervisor.
    pub supervisor: SupervisorConfig,
    /// Run.
    pub run: RunConfig,
    /// Log.
    pub log: LogConfig,
    /// CANopen backend (`--hal canopen`): bus timing, node ids, PDO set (optional section).
    pub canopen: CanopenConfig,
    /// Wall-clock executor (used with `--realtime`).
    pub realtime: RealtimeConfig,
    /// Declared operating inputs (`[inputs.<name>]`, [`inputs`]): record columns that set the
    /// operating point, and the plant parameters that depend on them.
    pub inputs: inputs::Inputs,
    /// What a fitted law in this config was fitted on (`[envelope]`, [`envelope`]); `None`
    /// when the config makes no such claim.
    pub envelope: Option<envelope::Envelope>,
    /// The spread of a fitted law for the band on its predictions (`[band]`,
    /// [`envelope::Band`]); `None` when the config states none.
    pub band: Option<envelope::Band>,
}

/// Control, setpoint, supervisor, run, log and realtime parameters, generated from the
/// `#[param(...)]` declarations on the fields of their sections (`#[derive(Params)]`), in
/// the order of `RIG_SECTIONS` and then of the fields.
pub fn control_params() -> &'static [Param] {
    static TABLE: LazyLock<Vec<Param>> = LazyLock::new(|| {
        let mut out = Vec::new();
        for (key, declare) in RIG_SECTIONS {
            out.extend(declare(key));
        }
        out
    });
    &TABLE
}

/// Sections of the rig config (besides the plant and `[canopen]`) that declare parameters,
/// with the function listing their registry entries under their key.
type Declare = fn(&str) -> Vec<Param>;
const RIG_SECTIONS: [(&str, Declare); 6] = [
    ("control", spec::table::<ControlConfig>),
    ("setpoint", spec::table::<SetpointConfig>),
    ("supervisor", spec::table::<SupervisorConfig>),
    ("run", spec::table::<RunConfig>),
    ("log", spec::table::<LogConfig>),
    ("realtime", spec::table::<RealtimeConfig>),
];

/// All registries (plant, control/run, CANopen), for lookups.
pub fn registries() -> [&'static [Param]; 3] {
    [spec::params(), control_params(), canopen_params()]
}

const RIG_KEYS: [&str; 11] = [
    "rig",
    "inputs",
    "envelope",
    "band",
    "control",
    "setpoint",
    "supervisor",
    "run",
    "log",
    "canopen",
    "realtime",
];

fn section<T: serde::de::DeserializeOwned>(
    root: &mut toml::Table,
    key: &str,
    required: bool,
    default: impl FnOnce() -> Option<T>,
) -> Result<T, ConfigError> {
    let tables = registries();
    match root.remove(key) {
        Some(v) => {
            if !v.is_table() {
                return Err(ConfigError::new(
                    key,
                    format!("expected a table [{key}], got {}", v.type_str()),
                ));
            }
            serde_path_to_error::deserialize(v).map_err(|e| tree::from_serde(key, e, &tables))
        }
        None if required => Err(ConfigError::new(
            key,
            format!("missing required section [{key}]"),
        )),
        None => default().ok_or_else(|| ConfigError::new(key, format!("missing section [{key}]"))),
    }
}

/// A top-level section that names its own keys (`[inputs]`, `[envelope]`, `[band]`: not
/// registry entries), taken out of the tree before the registry check: `None` when absent,
/// an error naming the key path when it is not `shape` (e.g. `[inputs.<name>]`) or does not
/// deserialise.
fn own_table<T: serde::de::DeserializeOwned>(
    value: Option<toml::Value>,
    key: &str,
    shape: &str,
) -> Result<Option<T>, ConfigError> {
    match value {
        None => Ok(None),
        Some(v) if v.is_table() => serde_path_to_error::deserialize(v)
            .map(Some)
            .map_err(|e| ConfigError::new(format!("{key}.{}", e.path()), e.inner().to_string())),
        Some(v) => Err(ConfigError::new(
            key,
            format!("expected a table {shape}, got {}", v.type_str()),
        )),
    }
}

impl RigConfig {
    /// Load and validate a config file.
    pub fn load(path: &Path) -> Result<RigConfig, ConfigError> {
        // A regular file of at most 16 MB (a FIFO or /dev/zero is refused, never read).
        let text =
            ehactl_input::read_bounded_string(path, ehactl_input::CONFIG_MAX_BYTES, "config")
                .map_err(|e| ConfigError::new(path.display().to_string(), e.reason))?;
        Self::from_toml_str(&text)
    }

    /// Parse and validate TOML text.
    pub fn from_toml_str(text: &str) -> Result<RigConfig, ConfigError> {
        let value: toml::Value = toml::from_str(text).map_err(|e| {
            let (line, col) = e
                .span()
                .map(|s| {
                    let before = &text[..s.start.min(text.len())];
                    (
                        before.matches('\n').count() + 1,
                        before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1,
                    )
                })
                .unwrap_or((0, 0));
            ConfigError::new(
                format!("line {line}, column {col}"),
                format!("TOML syntax error: {}", e.message()),
            )
        })?;
        Self::from_value(value)
    }

    /// Validate a TOML tree.
    pub fn from_value(mut value: toml::Value) -> Result<RigConfig, ConfigError> {
        let tables = registries();
        // `[inputs]` names its own keys (input names, parameter paths): not registry entries.
        let inputs_value = value.as_table_mut().and_then(|t| t.remove("inputs"));
        // `[envelope]` is a record of fitted data, not parameters either.
        let envelope_value = value.as_table_mut().and_then(|t| t.remove("envelope"));
        let band_value = value.as_table_mut().and_then(|t| t.remove("band"));
        tree::check_tree(&mut value, &tables)?;
        let toml::Value::Table(mut root) = value else {
            return Err(ConfigError::new("", "config must be a TOML table"));
        };
        let rig: RigInfo = section(&mut root, "rig", false, || Some(RigInfo::default()))?;
        let control: ControlConfig = section(&mut root, "control", true, || None)?;
        let setpoint: SetpointConfig = section(&mut root, "setpoint", true, || None)?;
        let supervisor: SupervisorConfig = section(&mut root, "supervisor", false, || {
            Some(SupervisorConfig::default())
        })?;
        let run: RunConfig = section(&mut root, "run", true, || None)?;
        let log: LogConfig = section(&mut root, "log", false, || Some(LogConfig::default()))?;
        let canopen: CanopenConfig = section(&mut root, "canopen", false, || {
            Some(CanopenConfig::default())
        })?;
        let realtime: RealtimeConfig = section(&mut root, "realtime", false, || {
            Some(RealtimeConfig::default())
        })?;
        let plant: PlantParams = serde_path_to_error::deserialize(toml::Value::Table(root))
            .map_err(|e| tree::from_serde("", e, &tables))?;
        let inputs: inputs::Inputs =
            own_table(inputs_value, "inputs", "[inputs.<name>]")?.unwrap_or_default();
        let envelope = own_table(envelope_value, "envelope", "[envelope]")?;
        let band = own_table(band_value, "band", "[band]")?;
        let cfg = RigConfig {
            rig,
            plant,
            control,
            setpoint,
            supervisor,
            run,
            log,
            canopen,
            realtime,
            inputs,
            envelope,
            band,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// Cross-field checks.
    pub fn validate(&self) -> Result<(), ConfigError> {
        ehactl_plant::model::validate(&self.plant)?;
        inputs::validate(&self.inputs, &self.plant)?;
        if let Some(env) = &self.envelope {
            envelope::validate(env, &self.inputs)?;
        }
        if let Some(band) = &self.band {
            envelope::validate_band(band, &self.inputs)?;
        }
        match self.control.mode {
            ControlMode::Force if self.control.pi.is_none() => {
                return Err(ConfigError::new(
                    "control.pi",
                    "missing section [control.pi]; required when control.mode = \"force\" (kp in V/V, integral in 1/s, error_scale in V/N)",
                ))
            }
            ControlMode::Position if self.control.pd.is_none() => {
                return Err(ConfigError::new(
                    "control.pd",
                    "missing section [control.pd]; required when control.mode = \"position\" (kp in V/m, td in s)",
                ))
            }
            _ => {}
        }
        self.validate_control()?;
        let s = &self.setpoint;
        let need = |ok: bool, field: &str, what: &str| -> Result<(), ConfigError> {
            if ok {
                Ok(())
            } else {
                Err(ConfigError::new(
                    format!("setpoint.{field}"),
                    what.to_string(),
                ))
            }
        };
        match s.kind {
            SetpointKind::Ramp => need(s.duration > 0.0, "duration", "ramp needs duration > 0 s")?,
            SetpointKind::Sine => need(s.f0 > 0.0, "f0", "sine needs f0 > 0 Hz")?,
            SetpointKind::Chirp | SetpointKind::StaticDynamic => {
                need(s.f0 > 0.0, "f0", "sweep needs f0 > 0 Hz")?;
                need(s.f1 > 0.0, "f1", "sweep needs f1 > 0 Hz")?;
                need(s.duration > 0.0, "duration", "sweep needs duration > 0 s")?;
                if s.sweep == Sweep::Stepped {
                    need(s.steps >= 1, "steps", "stepped sweep needs steps ≥ 1")?;
                }
            }
            SetpointKind::RandomSteps => {
                need(s.hold > 0.0, "hold", "random steps need hold > 0 s")?
            }
            SetpointKind::Step => {}
        }
        self.canopen.validate()?;
        // The safe command goes to the valve on every trip and at the end: it must be within
        // the valve's range (±valve.command_full_scale = ±100 % spool) and the command clamp.
        let sc = self.supervisor.safe_command;
        let fs = self.plant.valve.command_full_scale;
        let lim = self.supervisor.max_command.map_or(fs, |m| m.min(fs));
        if sc.is_nan() || sc.abs() > lim {
            return Err(ConfigError::new(
                "supervisor.safe_command",
                format!(
                    "{sc} V is outside the valve's range: expected |safe_command| <= {lim} V (valve.command_full_scale = {fs} V = 100 % spool{})",
                    self.supervisor
                        .max_command
                        .map_or(String::new(), |m| format!(", supervisor.max_command = {m} V"))
                ),
            ));
        }
        if self.realtime.spin >= self.timebase().period() {
            return Err(ConfigError::new(
                "realtime.spin",
                format!(
                    "busy-wait tail {} s must be below the control period {} s",
                    self.realtime.spin,
                    self.timebase().period()
                ),
            ));
        }
        let nyq = self.run.control_rate_hz / 2.0;
        let swept = matches!(s.kind, SetpointKind::Chirp | SetpointKind::StaticDynamic);
        for (field, f) in [("f0", s.f0), ("f1", s.f1)] {
            if (swept || (s.kind == SetpointKind::Sine && field == "f0")) && f >= nyq {
                return Err(ConfigError::new(
                    format!("setpoint.{field}"),
                    format!("frequency {f} Hz is at or above the Nyquist frequency {nyq} Hz of run.control_rate_hz"),
                ));
            }
        }
        self.validate_setpoint_range()?;
        if let (Some(lo), Some(hi)) = (self.supervisor.min_position, self.supervisor.max_position) {
            if lo >= hi {
                return Err(ConfigError::new(
                    "supervisor.min_position",
                    format!("min_position {lo} m must be below max_position {hi} m"),
                ));
            }
        }
        Ok(())
    }

    /// Controller limits against each other and the valve's input range.
    fn validate_control(&self) -> Result<(), ConfigError> {
        let fs = self.plant.valve.command_full_scale;
        let within_valve = |path: &str, u: f64| -> Result<(), ConfigError> {
            if u.abs() > fs {
                Err(ConfigError::new(
                    path,
                    format!("{u} V is beyond the valve's input range ±{fs} V (valve.command_full_scale)"),
                ))
            } else {
                Ok(())
            }
        };
        if let Some(pi) = &self.control.pi {
            if pi.u_min >= pi.u_max {
                return Err(ConfigError::new(
                    "control.pi.u_min",
                    format!("u_min {} V must be below u_max {} V", pi.u_min, pi.u_max),
                ));
            }
            within_valve("control.pi.u_min", pi.u_min)?;
            within_valve("control.pi.u_max", pi.u_max)?;
        }
        if let Some(pd) = &self.control.pd {
            within_valve("control.pd.u_max", pd.u_max)?;
        }
        if let Some(m) = self.supervisor.max_command {
            within_valve("supervisor.max_command", m)?;
        }
        Ok(())
    }

    /// The setpoint stays where the rig can go: inside the stroke (position), within what the
    /// supply pressure can push on the larger area (force).
    fn validate_setpoint_range(&self) -> Result<(), ConfigError> {
        let ((lo, lo_field), (hi, hi_field)) = ehactl_control::setpoint::envelope(&self.setpoint);
        let out = |field: &str, v: f64, what: String| {
            Err(ConfigError::new(
                format!("setpoint.{field}"),
                format!("the setpoint reaches {v} {what}"),
            ))
        };
        match self.control.mode {
            // Physical bounds only: a supervisor limit inside the setpoint's range is a
            // legitimate way to test a trip.
            ControlMode::Position => {
                let stroke = self.plant.cylinder.stroke;
                if lo < 0.0 {
                    return out(
                        lo_field,
                        lo,
                        "m, below 0 m (the stroke is [0, cylinder.stroke])".into(),
                    );
                }
                if hi > stroke {
                    return out(
                        hi_field,
                        hi,
                        format!("m, above cylinder.stroke = {stroke} m"),
                    );
                }
            }
            ControlMode::Force => {
                let c = &self.plant.cylinder;
                let f_max = self.plant.supply.pressure * c.area_a.max(c.area_b);
                for (field, v) in [(lo_field, lo), (hi_field, hi)] {
                    if v.abs() > f_max {
                        return out(field, v, format!("N, beyond ±{f_max:.6e} N (supply.pressure × the larger piston area: more than the cylinder can push)"));
                    }
                }
            }
            // Open loop: the setpoint is the valve command, which the valve clips at full
            // scale and the supervisor's max_command bounds; nothing to check here.
            ControlMode::OpenLoop => {}
        }
        Ok(())
    }

    /// The control timebase (`run.control_rate_hz`): the one owner of the control period,
    /// handed to the plant, the pacer and the backends.
    pub fn timebase(&self) -> Timebase {
        Timebase::at_rate_hz(self.run.control_rate_hz)
    }

    /// PI gains from the config.
    pub fn pi_gains(&self) -> Option<PiGains> {
        self.control.pi.as_ref().map(|p| PiGains {
            kp: p.kp,
            integral: p.integral,
            error_scale: p.error_scale,
            u_min: p.u_min,
            u_max: p.u_max,
            tracking: p.tracking,
            feedforward: p.feedforward,
        })
    }

    /// PD gains from the config.
    pub fn pd_gains(&self) -> Option<PdGains> {
        self.control.pd.as_ref().map(|p| PdGains {
            kp: p.kp,
            td: p.td,
            filter_n: p.filter_n,
            u_max: p.u_max,
            feedforward_velocity: p.feedforward_velocity,
        })
    }

    /// The supervisor's settings as a run uses them: the `[supervisor]` section with the
    /// following-error bound filled in for a closed loop that does not set it, so that a
    /// config without the section is still supervised: twice the largest |setpoint| over the
    /// setpoint's envelope (an error no loop whose feedback stays between the setpoint's
    /// extremes and its mirror image can reach), at least 10 % of the actuator's range (the
    /// stroke for a position loop, supply.pressure × the larger piston area for a force
    /// loop), so that a setpoint near zero does not make the bound the sensor noise. Open
    /// loop has no feedback and no following error: the field stays as it is, unchecked.
    pub fn supervisor_settings(&self) -> SupervisorConfig {
        let mut s = self.supervisor.clone();
        if s.following_error.is_none() {
            s.following_error = self.default_following_error();
        }
        s
    }

    /// The derived following-error bound of [`RigConfig::supervisor_settings`] (N or m); None
    /// in open loop.
    pub fn default_following_error(&self) -> Option<f64> {
        let c = &self.plant.cylinder;
        let range = match self.control.mode {
            ControlMode::Position => c.stroke,
            ControlMode::Force => self.plant.supply.pressure * c.area_a.max(c.area_b),
            ControlMode::OpenLoop => return None,
        };
        let ((lo, _), (hi, _)) = ehactl_control::setpoint::envelope(&self.setpoint);
        Some((2.0 * lo.abs().max(hi.abs())).max(0.1 * range))
    }

    /// The control law `control.mode` selects, with its gains (a validated config has the
    /// section its mode needs).
    pub fn controller(&self) -> Controller {
        match self.control.mode {
            ControlMode::Force => Controller::Force(Pi::new(self.pi_gains().expect("validated"))),
            ControlMode::Position => {
                Controller::Position(Pd::new(self.pd_gains().expect("validated")))
            }
            ControlMode::OpenLoop => Controller::OpenLoop,
        }
    }

    /// The whole config as a TOML tree (defaults filled in).
    pub fn to_value(&self) -> toml::Value {
        let mut root = match toml::Value::try_from(&self.plant) {
            Ok(toml::Value::Table(t)) => t,
            _ => toml::Table::new(),
        };
        let mut put = |k: &str, v: Result<toml::Value, toml::ser::Error>| {
            if let Ok(v) = v {
                root.insert(k.to_string(), v);
            }
        };
        put("rig", toml::Value::try_from(&self.rig));
        put("control", toml::Value::try_from(&self.control));
        put("setpoint", toml::Value::try_from(&self.setpoint));
        put("supervisor", toml::Value::try_from(&self.supervisor));
        put("run", toml::Value::try_from(&self.run));
        put("log", toml::Value::try_from(&self.log));
        put("canopen", toml::Value::try_from(&self.canopen));
        put("realtime", toml::Value::try_from(&self.realtime));
        if !self.inputs.is_empty() {
            put("inputs", toml::Value::try_from(&self.inputs));
        }
        if let Some(env) = &self.envelope {
            put("envelope", toml::Value::try_from(env));
        }
        if let Some(band) = &self.band {
            put("band", toml::Value::try_from(band));
        }
        toml::Value::Table(root)
    }

    /// The whole config as TOML text.
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(&self.to_value()).unwrap_or_default()
    }

    /// The whole config as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self.to_value()).unwrap_or(serde_json::Value::Null)
    }

    /// Keys of the top level that belong to the rig rather than the plant.
    pub fn rig_keys() -> &'static [&'static str] {
        &RIG_KEYS
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ehactl_plant::spec::{Kind, ParamTree, PathErrorKind, Range};

    /// A setpoint out of the rig's reach names the field that put it there: the amplitude
    /// when it is the larger term of `offset ± amplitude`, the offset otherwise.
    #[test]
    fn out_of_reach_setpoint_names_the_field_responsible() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/sahu2022_force.toml");
        let cfg = RigConfig::load(&path).unwrap();
        for (field, offset, amplitude) in [
            ("setpoint.amplitude", 500.0, 1e12),
            ("setpoint.offset", 1e12, 100.0),
            ("setpoint.offset", -1e12, 0.0),
        ] {
            let mut tree = cfg.to_value();
            *tree::get_mut(&mut tree, "setpoint.offset").unwrap() = toml::Value::Float(offset);
            *tree::get_mut(&mut tree, "setpoint.amplitude").unwrap() =
                toml::Value::Float(amplitude);
            let e = RigConfig::from_value(tree).unwrap_err();
            assert_eq!(e.path, field, "offset {offset}, amplitude {amplitude}: {e}");
            assert!(e.message.contains("the setpoint reaches"), "{e}");
        }
    }

    /// Without `supervisor.following_error` a closed loop is still supervised: twice the
    /// largest |setpoint| (Sahu 2022: 785 N static + 196 N dynamic → 1962 N; Dindorf 2022:
    /// the 0.6 m step → 1.2 m), at least a tenth of the actuator's range (a 1 N setpoint on
    /// Sahu's 20 MPa × 2.364e-4 m² cylinder → 472.8 N); an explicit value is kept; open loop
    /// gets none.
    #[test]
    fn an_absent_following_error_is_derived_from_the_setpoint() {
        let load = |name: &str| {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../configs")
                .join(name);
            let mut cfg = RigConfig::load(&path).unwrap();
            cfg.supervisor.following_error = None;
            cfg
        };
        let mut sahu = load("sahu2022_force.toml");
        let close = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() <= 1e-9 * b);
        assert!(close(
            sahu.supervisor_settings().following_error,
            2.0 * (785.0 + 196.0)
        ));
        sahu.setpoint.offset = 1.0;
        sahu.setpoint.amplitude = 0.0;
        assert!(close(
            sahu.supervisor_settings().following_error,
            0.1 * 20.0e6 * 2.364e-4
        ));
        sahu.supervisor.following_error = Some(600.0);
        assert_eq!(sahu.supervisor_settings().following_error, Some(600.0));
        let boom = load("dindorf2022_boom.toml");
        assert!(close(boom.supervisor_settings().following_error, 1.2));
        let open = load("ideko_machine_tool.toml");
        assert_eq!(open.supervisor_settings().following_error, None);
    }

    /// A value admitted by `r`, different for each `i`.
    fn admitted(r: Range, i: usize) -> f64 {
        let t = 0.3 + 0.4 * (i as f64 / 100.0);
        match r {
            Range::Within(lo, hi) => lo + t * (hi - lo),
            Range::Finite => -1.5 * t,
            Range::Positive | Range::NonNegative => 2.5 * t,
            Range::PositiveAtMost(hi) => t * hi,
        }
    }

    /// Every float entry of a section writes and reads back through the generated path
    /// accessor and lands at its registry path in the section's TOML (so the registry path,
    /// serde's key, e.g. `setpoint.final` for the field `final_value`, and the field agree);
    /// every other entry is refused by the float accessor but present in the TOML.
    fn round_trip<T: ParamTree + Serialize>(key: &str, s: &mut T) -> usize {
        let entries = spec::table::<T>(key);
        assert!(!entries.is_empty(), "{key}");
        let mut floats = 0;
        for (i, e) in entries.iter().enumerate() {
            let rel = e.path.strip_prefix(key).unwrap().strip_prefix('.').unwrap();
            if e.kind == Kind::Float {
                let v = admitted(e.range, i);
                s.set_path(rel, v).unwrap();
                assert_eq!(s.get_path(rel), Some(v), "{}", e.path);
                let tree = toml::Value::try_from(&*s).unwrap();
                assert_eq!(
                    tree::get(&tree, rel).and_then(|x| x.as_float()),
                    Some(v),
                    "{}",
                    e.path
                );
                floats += 1;
            } else {
                assert_eq!(
                    s.set_path(rel, 1.0).unwrap_err().kind,
                    PathErrorKind::NotFloat,
                    "{}",
                    e.path
                );
                let tree = toml::Value::try_from(&*s).unwrap();
                assert!(tree::get(&tree, rel).is_some(), "{} not serialised", e.path);
            }
        }
        floats
    }

    #[test]
    fn every_rig_section_path_round_trips() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/sahu2022_force.toml");
        let mut cfg = RigConfig::load(&path).unwrap();
        cfg.control.pd = Some(PdConfig {
            kp: 1.0,
            td: 0.0,
            filter_n: 0.0,
            u_max: 10.0,
            feedforward_velocity: 0.0,
        });
        let n = round_trip("control", &mut cfg.control)
            + round_trip("setpoint", &mut cfg.setpoint)
            + round_trip("supervisor", &mut cfg.supervisor)
            + round_trip("run", &mut cfg.run)
            + round_trip("log", &mut cfg.log)
            + round_trip("realtime", &mut cfg.realtime)
            + round_trip("canopen", &mut cfg.canopen);
        assert_eq!(n, 41, "float parameters outside the plant");
        // The renamed field: registry path, accessor and serde key `final`.
        cfg.setpoint.set_path("final", 12.5).unwrap();
        assert_eq!(cfg.setpoint.final_value, 12.5);
        // Absent optional values become Some; absent sections are refused.
        assert_eq!(
            cfg.supervisor.get_path("pressure_range"),
            Some(admitted(Range::Positive, 10))
        );
        let mut c = cfg.control.clone();
        c.pi = None;
        assert_eq!(
            c.set_path("pi.kp", 0.5).unwrap_err().kind,
            PathErrorKind::Absent
        );
        assert_eq!(
            c.set_path("pi.nope", 0.5).unwrap_err().kind,
            PathErrorKind::Unknown
        );
    }

    /// The registry is the one [`RigConfig::from_value`] checks: a value outside a derived
    /// range is refused with the path and the declared unit, for each kind of field.
    #[test]
    fn derived_ranges_are_enforced_by_the_loader() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/sahu2022_force.toml");
        let base = std::fs::read_to_string(path).unwrap();
        for (add, field, unit) in [
            ("[realtime]\ncpu = -2\n", "realtime.cpu", "-"),
            ("[realtime]\npriority = 100\n", "realtime.priority", "-"),
            (
                "[log]\nqueue_capacity = 8\n",
                "log.queue_capacity",
                "records",
            ),
            (
                "[canopen]\nvalve_status_pdo = 1\n",
                "canopen.valve_status_pdo",
                "true or false",
            ),
            (
                "[canopen]\nvalve_node_id = 128\n",
                "canopen.valve_node_id",
                "-",
            ),
        ] {
            let e = RigConfig::from_toml_str(&format!("{base}\n{add}")).unwrap_err();
            assert_eq!(e.path, field, "{e}");
            assert!(e.message.contains(unit), "{e}");
        }
        let e =
            RigConfig::from_toml_str(&base.replace("max_pressure = 25.0e6", "max_pressure = -1.0"))
                .unwrap_err();
        assert_eq!(e.path, "supervisor.max_pressure");
        assert!(e.message.contains("in Pa (pressure trip limit)"), "{e}");
    }
}
