//! # ehactl-hal
//!
//! The hardware abstraction of ehactl, in the manner of ros2_control's hardware interface:
//! one [`Hal`] trait with `read(time, period)` / `write(time, period)` called once per
//! cycle. The controller never knows which backend it talks to. This crate holds:
//! - [`Hal`] and its error type,
//! - [`pacer::Pacer`], what starts each cycle (simulated time or a wall-clock executor), and
//!   the timing report it hands back,
//! - [`Timebase`], the one owner of the control period (built from `run.control_rate_hz`
//!   and handed to the plant, the pacer and the backends),
//! - [`sim::SimHal`], the in-process nonlinear plant advanced one control period per write,
//! - [`input`], bounded reads of the user's input files (regular files of a capped size).
//!
//! The cycle records, the MCAP logger, the JSON schemas and log recovery are in `ehactl-log`
//! (crates/log); the measurement, plant-state and event types in `ehactl-types`.
#![deny(missing_docs)]

pub mod input;
pub mod pacer;
pub mod sim;

pub use ehactl_types::{Measurements, PlantState};

/// The control period, owned in one place. Built once from the config's
/// `run.control_rate_hz` and handed to the plant (its discretisation step), the pacer (its
/// deadline grid) and the backends (SYNC period, staleness limits); the time of cycle `k` is
/// `k · period` everywhere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timebase {
    rate_hz: f64,
    period_ns: u64,
}

impl Timebase {
    /// A timebase at a rate the caller has validated (the config loader checks
    /// `run.control_rate_hz` ∈ [1, 1e6] Hz). An unusable rate gives a non-finite or zero
    /// period, which `Plant::configure` and the pacer reject; nothing here panics.
    pub fn at_rate_hz(rate_hz: f64) -> Timebase {
        let period_ns = 1e9 / rate_hz;
        Timebase {
            rate_hz,
            period_ns: if period_ns.is_finite() && period_ns >= 1.0 {
                period_ns.round() as u64
            } else {
                1
            },
        }
    }

    /// Control rate (Hz).
    #[inline]
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Control period (s), `1 / rate_hz`.
    #[inline]
    pub fn period(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// Control period rounded to whole nanoseconds (ns), the wall-clock pacer's grid.
    #[inline]
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Time of cycle `k` (s) on the control grid.
    #[inline]
    pub fn time_of(&self, k: u64) -> f64 {
        k as f64 * self.period()
    }

    /// Number of whole cycles in `duration` (s), rounded to the nearest cycle.
    #[inline]
    pub fn cycles_in(&self, duration: f64) -> u64 {
        (duration * self.rate_hz).round().max(0.0) as u64
    }

    /// Whether a measured period (s) is off the nominal one by more than `tolerance`
    /// (relative, -): used by backends to count late or early cycles.
    #[inline]
    pub fn is_off(&self, measured: f64, tolerance: f64) -> bool {
        (measured - self.period()).abs() > tolerance * self.period()
    }
}

/// Why a backend could not complete a read or write. `Copy` so that it can be raised in
/// the cycle without allocating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HalError {
    /// The simulated plant produced a non-finite state.
    Numerical {
        /// Time (s).
        t: f64,
        /// Offending state.
        what: &'static str,
    },
    /// A device reported a fault or stopped answering.
    Device {
        /// Device-specific code.
        code: u32,
        /// Short description.
        what: &'static str,
    },
}

impl HalError {
    /// The state or device concerned (the event channel of a fault).
    pub fn what(&self) -> &'static str {
        match self {
            HalError::Numerical { what, .. } | HalError::Device { what, .. } => what,
        }
    }
}

impl std::fmt::Display for HalError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HalError::Numerical { t, what } => {
                write!(f, "plant state `{what}` became non-finite at t = {t} s")
            }
            HalError::Device { code, what } => write!(f, "device fault {code:#x}: {what}"),
        }
    }
}

impl std::error::Error for HalError {}

/// Hardware interface used by the control loop, once per cycle.
pub trait Hal {
    /// Backend name for logs ("sim", "canopen").
    fn name(&self) -> &'static str;

    /// Read every sensor at the start of the cycle at time `t` (s, on the control grid);
    /// `period` is the measured time since the previous cycle started (s; the nominal
    /// period under simulated time and for the first cycle), as in ros2_control. Backends
    /// use it or check it against their [`Timebase`]. Real-time safe: no allocation, no
    /// lock, no blocking I/O.
    fn read(&mut self, t: f64, period: f64) -> Result<Measurements, HalError>;

    /// Write the valve command `command` (V) at `t` (s); `period` is the measured period
    /// as in [`Hal::read`]. The simulation backend advances the plant by one nominal period
    /// here. Real-time safe.
    fn write(&mut self, t: f64, period: f64, command: f64) -> Result<(), HalError>;

    /// Put the actuator in its safe state (valve to `command`, typically 0 V). Called on a
    /// trip, on a signal and at the end of every run; may block briefly.
    fn safe_stop(&mut self, command: f64) -> Result<(), HalError>;

    /// Ground-truth plant state when the backend knows it (simulation), for logging.
    fn plant_state(&self) -> Option<PlantState> {
        None
    }

    /// Raw bus frames to log (CAN backends): the session attaches this queue to the MCAP
    /// logger, which writes every frame to the `/can` channel.
    fn frame_log(&self) -> Option<std::sync::Arc<ehactl_log::logger::FrameLog>> {
        None
    }

    /// Backend-specific figures for the run summary (e.g. `bus_load_percent`), as a JSON
    /// object whose keys are added to the summary. Called once after the loop.
    fn report(&self) -> Option<serde_json::Value> {
        None
    }
}
