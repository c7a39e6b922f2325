//! Live gain and setpoint changes while a run is going: a double buffer handed over at a
//! cycle boundary, never a lock in the loop.
//!
//! The loop owns the *front* buffer (its controller gains and setpoint generator). A
//! change is prepared off the loop (parse, range check, full config validation) and pushed
//! into the *back* buffer: a one-slot [`crossbeam_queue::ArrayQueue`] (lock-free,
//! preallocated at construction, so neither side allocates or locks when handing over). At
//! the start of the next cycle the loop pops the slot and copies the change into its front
//! buffer (plain numbers, no allocation). Writers are serialised among themselves and wait
//! (off the loop) until the previous change has been taken, so no change is ever lost or
//! applied half-way. Every change is logged as a `param_change` event at the cycle it
//! took effect.
//!
//! Why a one-slot queue and not a triple buffer (`triple_buffer` crate): a triple buffer
//! keeps only the latest value, so a change published twice before the loop looks would
//! lose the first one's events, and its reader half needs `&mut` access, which the loop
//! (sharing `&LiveParams` with the control socket) does not have. The queue hands over
//! every change exactly once through a shared reference, with no `unsafe` here.

use crossbeam_queue::ArrayQueue;
use ehactl_config::{ControlMode, RigConfig};
use ehactl_control::controller::Controller;
use ehactl_control::setpoint::Setpoint;
use ehactl_log::logger::{Note, NoteLog};
use ehactl_log::record::{Event, EventKind, Severity};
use ehactl_plant::spec::Param;
use ehactl_plant::ConfigError;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Most assignments in one change (they land together, in one cycle).
pub const MAX_CHANGES: usize = 8;

/// One assignment: the registry entry (static path and unit) and the new value (SI).
#[derive(Debug, Clone, Copy)]
pub struct Assignment {
    /// Parameter (dotted path, unit) from the config registry.
    pub param: &'static Param,
    /// New value in the parameter's unit.
    pub value: f64,
}

/// A complete new set of tunables plus what changed (for the events).
#[derive(Debug, Clone)]
pub struct Update {
    /// New controller gains (the whole law; its state is kept).
    pub controller: Tunables,
    /// New setpoint generator.
    pub setpoint: Setpoint,
    /// The assignments that produced it.
    pub changes: [Option<Assignment>; MAX_CHANGES],
}

/// Gains of the configured law.
#[derive(Debug, Clone, Copy)]
pub enum Tunables {
    /// PI gains (force mode).
    Pi(ehactl_control::pi::PiGains),
    /// PD gains (position mode).
    Pd(ehactl_control::pd::PdGains),
    /// Open loop: nothing to tune.
    None,
}

/// The back buffer shared between the writer (control socket, CLI) and the loop.
pub struct LiveParams {
    /// The back buffer: at most one change waiting for the loop.
    slot: ArrayQueue<Update>,
    writers: Mutex<()>,
    published: AtomicU64,
    applied: AtomicU64,
    applied_cycle: AtomicU64,
    /// Refused changes, for the run's `/events` (see [`LiveParams::refused`]).
    notes: Arc<NoteLog>,
    /// The loop's last cycle boundary: cycle and time (f64 bits), stamped on refusals.
    now_cycle: AtomicU64,
    now_t: AtomicU64,
}

impl std::fmt::Debug for LiveParams {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveParams")
            .field("published", &self.published.load(Ordering::Relaxed))
            .field("applied", &self.applied.load(Ordering::Relaxed))
            .finish()
    }
}

impl Default for LiveParams {
    fn default() -> Self {
        Self::new()
    }
}

/// Why a change was not published.
#[derive(Debug)]
pub enum LiveError {
    /// Bad assignment (unknown or non-tunable path, bad value, invalid config).
    Config(ConfigError),
    /// The loop did not take the previous change in time (not running?).
    Timeout,
}

impl std::fmt::Display for LiveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LiveError::Config(e) => e.fmt(f),
            LiveError::Timeout => {
                write!(f, "the control loop is not taking changes (not running?)")
            }
        }
    }
}

impl std::error::Error for LiveError {}

impl LiveParams {
    /// Empty back buffer.
    pub fn new() -> Self {
        Self {
            slot: ArrayQueue::new(1),
            writers: Mutex::new(()),
            published: AtomicU64::new(0),
            applied: AtomicU64::new(0),
            applied_cycle: AtomicU64::new(u64::MAX),
            notes: Arc::new(NoteLog::new(256)),
            now_cycle: AtomicU64::new(0),
            now_t: AtomicU64::new(0f64.to_bits()),
        }
    }

    /// Publish `update` (off the loop). Waits up to `timeout` for the loop to take the
    /// previous change; returns the sequence number of this change (1, 2, …).
    pub fn publish(&self, update: Update, timeout: Duration) -> Result<u64, LiveError> {
        let _w = self.writers.lock().unwrap_or_else(|p| p.into_inner());
        let t0 = Instant::now();
        let seq = self.published.load(Ordering::Relaxed) + 1;
        let mut update = update;
        // The sequence number is counted before the push: once pushed, the loop may apply
        // the change (and count it in `applied`) at once.
        self.published.store(seq, Ordering::Relaxed);
        while let Err(back) = self.slot.push(update) {
            if t0.elapsed() > timeout {
                self.published.store(seq - 1, Ordering::Relaxed);
                return Err(LiveError::Timeout);
            }
            update = back;
            std::thread::sleep(Duration::from_micros(50));
        }
        Ok(seq)
    }

    /// Wait (off the loop) until change `seq` has been applied; returns the cycle at whose
    /// boundary it took effect.
    pub fn wait_applied(&self, seq: u64, timeout: Duration) -> Option<u64> {
        let t0 = Instant::now();
        loop {
            if self.applied.load(Ordering::Acquire) >= seq {
                return Some(self.applied_cycle.load(Ordering::Relaxed));
            }
            if t0.elapsed() > timeout {
                return None;
            }
            std::thread::sleep(Duration::from_micros(50));
        }
    }

    /// The queue of refused changes; the run's logger writes them to `/events`.
    pub fn notes(&self) -> Arc<NoteLog> {
        self.notes.clone()
    }

    /// Record a refused change (off the loop): a `param_refused` warning carrying the
    /// request line and the reason goes to the run's `/events` (stamped with the loop's
    /// last cycle), and the same line to stderr. `param` names the refused field when
    /// known (a registry path), else `control_socket`.
    pub fn refused(&self, request: &str, reason: &str, param: Option<&'static str>) {
        let cycle = self.now_cycle.load(Ordering::Relaxed);
        let t = f64::from_bits(self.now_t.load(Ordering::Relaxed));
        let ev = Event::note(
            t,
            cycle,
            Severity::Warning,
            EventKind::ParamRefused,
            param.unwrap_or("control_socket"),
        );
        // Bounded: a hostile client cannot make a note (or stderr line) of megabytes.
        let request = clip(request, 512);
        let reason = clip(reason, 512);
        eprintln!("ehactl: refused live change `{request}`: {reason}");
        self.notes.push(Note {
            event: ev,
            fields: vec![("request", request), ("reason", reason)],
        });
    }

    /// Changes applied so far.
    pub fn applied_count(&self) -> u64 {
        self.applied.load(Ordering::Acquire)
    }

    /// Called by the loop at the boundary before cycle `k` (time `t`, s): if a change is
    /// pending, copy it into the front buffer (`controller`, `setpoint`) and log one
    /// `param_change` event per assignment. Wait-free, allocation-free.
    #[inline]
    pub fn apply_pending(
        &self,
        k: u64,
        t: f64,
        controller: &mut Controller,
        setpoint: &mut Setpoint,
        event: &mut dyn FnMut(Event),
    ) {
        self.now_cycle.store(k, Ordering::Relaxed);
        self.now_t.store(t.to_bits(), Ordering::Relaxed);
        let Some(u) = self.slot.pop() else {
            return;
        };
        match (controller, u.controller) {
            (Controller::Force(pi), Tunables::Pi(g)) => pi.gains = g,
            (Controller::Position(pd), Tunables::Pd(g)) => pd.gains = g,
            _ => {}
        }
        // `Update` is plain numbers (no heap), so moving it out and dropping it frees nothing.
        *setpoint = u.setpoint;
        for a in u.changes.iter().flatten() {
            event(Event {
                t,
                cycle: k,
                severity: Severity::Info,
                kind: EventKind::ParamChange,
                channel: a.param.path,
                value: a.value,
                limit: f64::NAN,
                unit: a.param.unit,
            });
        }
        self.applied_cycle.store(k, Ordering::Relaxed);
        let n = self.applied.load(Ordering::Relaxed) + 1;
        self.applied.store(n, Ordering::Release);
    }
}

/// `text` cut to at most `max` bytes (on a character boundary), marked when cut.
fn clip(text: &str, max: usize) -> String {
    if text.len() <= max {
        return text.to_string();
    }
    let mut end = max;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}… ({} bytes)", &text[..end], text.len())
}

/// Whether `path` may be changed while running a config in `mode`.
fn tunable(path: &str, mode: ControlMode) -> bool {
    match mode {
        ControlMode::Force => path.starts_with("control.pi.") || path.starts_with("setpoint."),
        ControlMode::Position => path.starts_with("control.pd.") || path.starts_with("setpoint."),
        ControlMode::OpenLoop => path.starts_with("setpoint."),
    }
}

/// Parse `path=value` (value in the parameter's unit, as listed by `ehactl params`).
pub fn parse_assignment(text: &str) -> Result<(&str, f64), ConfigError> {
    let Some((path, value)) = text.split_once('=') else {
        return Err(ConfigError::new(
            text,
            "expected PATH=VALUE, e.g. control.pi.kp=0.5",
        ));
    };
    let path = path.trim();
    let value = value.trim();
    let v: f64 = value
        .parse()
        .map_err(|_| ConfigError::new(path, format!("`{value}` is not a number")))?;
    Ok((path, v))
}

/// Apply `assignments` to `cfg` (the config as running), validating each against the
/// registry and the whole config as `ehactl run` would; returns the update to publish.
/// `cfg` is changed only if everything is valid.
pub fn prepare(cfg: &mut RigConfig, assignments: &[(&str, f64)]) -> Result<Update, ConfigError> {
    if assignments.is_empty() {
        return Err(ConfigError::new("", "no assignment given (PATH=VALUE)"));
    }
    if assignments.len() > MAX_CHANGES {
        return Err(ConfigError::new(
            "",
            format!("at most {MAX_CHANGES} assignments per change"),
        ));
    }
    let mut tree = cfg.to_value();
    let mut changes = [None; MAX_CHANGES];
    for (i, &(path, value)) in assignments.iter().enumerate() {
        let param = ehactl_config::registries()
            .into_iter()
            .flat_map(|t| t.iter())
            .find(|p| p.path == path)
            .ok_or_else(|| ConfigError::new(path, "unknown parameter (see `ehactl params`)"))?;
        if !tunable(path, cfg.control.mode) {
            return Err(ConfigError::new(
                path,
                format!(
                    "cannot be changed while running a {:?} config; live changes accept control.{}.* and setpoint.*",
                    cfg.control.mode,
                    match cfg.control.mode {
                        ControlMode::Force => "pi",
                        ControlMode::Position => "pd",
                        ControlMode::OpenLoop => "(none)",
                    }
                )
                .to_lowercase(),
            ));
        }
        let slot = ehactl_config::tree::get_mut(&mut tree, path)
            .ok_or_else(|| ConfigError::new(path, "not present in the running config"))?;
        *slot = match param.kind {
            ehactl_plant::spec::Kind::Integer => {
                if value.fract() != 0.0 || value < 0.0 {
                    return Err(ConfigError::new(
                        path,
                        format!(
                            "got {value}, expected a non-negative integer ({})",
                            param.unit
                        ),
                    ));
                }
                toml::Value::Integer(value as i64)
            }
            _ => toml::Value::Float(value),
        };
        changes[i] = Some(Assignment { param, value });
    }
    let new_cfg = RigConfig::from_value(tree)?;
    let controller = match new_cfg.control.mode {
        ControlMode::Force => Tunables::Pi(new_cfg.pi_gains().expect("validated")),
        ControlMode::Position => Tunables::Pd(new_cfg.pd_gains().expect("validated")),
        ControlMode::OpenLoop => Tunables::None,
    };
    let update = Update {
        controller,
        setpoint: Setpoint::new(&new_cfg.setpoint),
        changes,
    };
    *cfg = new_cfg;
    Ok(update)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Changes are handed over one at a time and never overwritten: a second publish waits
    /// for the loop to take the first (and times out cleanly if it does not), then both
    /// changes reach the loop in order, each with its event.
    #[test]
    fn every_change_is_taken_once_in_order() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/sahu2022_force.toml");
        let mut cfg = RigConfig::load(&path).unwrap();
        let mut controller = cfg.controller();
        let mut setpoint = Setpoint::new(&cfg.setpoint);
        let live = LiveParams::new();
        let a = prepare(&mut cfg, &[("control.pi.kp", 0.31)]).unwrap();
        let b = prepare(&mut cfg, &[("control.pi.kp", 0.32)]).unwrap();
        assert_eq!(live.publish(a, Duration::from_secs(1)).unwrap(), 1);
        let e = live
            .publish(b.clone(), Duration::from_millis(5))
            .unwrap_err();
        assert!(matches!(e, LiveError::Timeout), "{e}");
        let mut events = Vec::new();
        let kp = |c: &Controller| match c {
            Controller::Force(pi) => pi.gains.kp,
            _ => unreachable!("force config"),
        };
        live.apply_pending(10, 0.002, &mut controller, &mut setpoint, &mut |e| {
            events.push(e)
        });
        assert_eq!(kp(&controller), 0.31);
        assert_eq!(live.publish(b, Duration::from_secs(1)).unwrap(), 2);
        live.apply_pending(11, 0.0022, &mut controller, &mut setpoint, &mut |e| {
            events.push(e)
        });
        live.apply_pending(12, 0.0024, &mut controller, &mut setpoint, &mut |e| {
            events.push(e)
        });
        assert_eq!(kp(&controller), 0.32);
        assert_eq!(live.applied_count(), 2);
        assert_eq!(live.wait_applied(2, Duration::ZERO), Some(11));
        let got: Vec<(u64, f64)> = events.iter().map(|e| (e.cycle, e.value)).collect();
        assert_eq!(got, [(10, 0.31), (11, 0.32)]);
    }
}
