//! Live gain and setpoint changes while a run is going: a double buffer handed over at a
//! cycle boundary, never a lock in the loop.
//!
//! The loop owns the *front* buffer (its controller gains and setpoint generator). A
//! change is prepared off the loop (parse, range check, full config validation), written
//! into the *back* buffer ([`LiveParams`]' single slot) and published with one atomic
//! store. At the start of the next cycle the loop claims the slot with one
//! compare-and-swap, copies it into its front buffer (plain numbers, no allocation) and
//! releases it: wait-free for the loop. Writers are serialised among themselves and wait
//! (off the loop) until the previous change has been taken, so no change is ever lost or
//! applied half-way. Every change is logged as a `param_change` event at the cycle it
//! took effect.

use crate::runloop::Controller;
use ehactl_config::{ControlMode, RigConfig};
use ehactl_control::setpoint::Setpoint;
use ehactl_hal::record::{Event, EventKind, Severity};
use ehactl_plant::spec::Param;
use ehactl_plant::ConfigError;
use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Most assignments in one change (they land together, in one cycle).
pub const MAX_CHANGES: usize = 8;

const EMPTY: u8 = 0;
const FULL: u8 = 1;
const TAKING: u8 = 2;

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
    state: AtomicU8,
    slot: UnsafeCell<Option<Update>>,
    writers: Mutex<()>,
    published: AtomicU64,
    applied: AtomicU64,
    applied_cycle: AtomicU64,
}

// SAFETY: `slot` is only written by a writer holding `writers` while `state` is EMPTY
// (the loop never touches the slot then), and only read by the loop between its
// FULL→TAKING compare-and-swap (Acquire) and its TAKING→EMPTY store (Release); writers do
// not touch it until they observe EMPTY (Acquire). So accesses never overlap.
unsafe impl Sync for LiveParams {}

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
            state: AtomicU8::new(EMPTY),
            slot: UnsafeCell::new(None),
            writers: Mutex::new(()),
            published: AtomicU64::new(0),
            applied: AtomicU64::new(0),
            applied_cycle: AtomicU64::new(u64::MAX),
        }
    }

    /// Publish `update` (off the loop). Waits up to `timeout` for the loop to take the
    /// previous change; returns the sequence number of this change (1, 2, …).
    pub fn publish(&self, update: Update, timeout: Duration) -> Result<u64, LiveError> {
        let _w = self.writers.lock().unwrap_or_else(|p| p.into_inner());
        let t0 = Instant::now();
        while self.state.load(Ordering::Acquire) != EMPTY {
            if t0.elapsed() > timeout {
                return Err(LiveError::Timeout);
            }
            std::thread::sleep(Duration::from_micros(50));
        }
        // SAFETY: state is EMPTY and we are the only writer: the loop does not access the
        // slot until we store FULL below.
        unsafe { *self.slot.get() = Some(update) };
        let seq = self.published.load(Ordering::Relaxed) + 1;
        self.published.store(seq, Ordering::Relaxed);
        self.state.store(FULL, Ordering::Release);
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
        if self.state.load(Ordering::Relaxed) != FULL {
            return;
        }
        if self
            .state
            .compare_exchange(FULL, TAKING, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            return;
        }
        // SAFETY: TAKING: the writers wait for EMPTY, so the slot is ours until the store.
        let slot = unsafe { &*self.slot.get() };
        if let Some(u) = slot {
            match (controller, u.controller) {
                (Controller::Force(pi), Tunables::Pi(g)) => pi.gains = g,
                (Controller::Position(pd), Tunables::Pd(g)) => pd.gains = g,
                _ => {}
            }
            setpoint.clone_from(&u.setpoint);
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
        }
        self.applied_cycle.store(k, Ordering::Relaxed);
        let n = self.applied.load(Ordering::Relaxed) + 1;
        self.applied.store(n, Ordering::Release);
        self.state.store(EMPTY, Ordering::Release);
    }
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
        let slot = ehactl_plant::spec::get_mut(&mut tree, path)
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
