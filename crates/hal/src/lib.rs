//! # ehactl-hal
//!
//! The hardware abstraction of ehactl, in the manner of ros2_control's hardware interface:
//! one [`Hal`] trait with `read(time, period)` / `write(time, period)` called once per
//! cycle. The controller never knows which backend it talks to. This crate holds:
//! - [`Hal`] and its error type,
//! - [`pacer::Pacer`], what starts each cycle (simulated time or a wall-clock executor), and
//!   the timing report it hands back,
//! - [`clock`], the time sources (monotonic, manual, scripted) of the wall-clock pacer and
//!   of the CANopen start-up and backend,
//! - [`Timebase`], the one owner of the control period (built from `run.control_rate_hz`
//!   and handed to the plant, the pacer and the backends; defined in `ehactl-types` so that
//!   the config reaches it without this crate, re-exported here).
//!
//! The contract is bare: it compiles neither the plant nor the logger. The simulated
//! backend (`SimHal`, the plant behind this trait) is `ehactl_runtime::sim`; the cycle
//! records, the MCAP logger, the JSON schemas and log recovery are in `ehactl-log`
//! (crates/log); the measurement, plant-state, event, cycle-timing and frame-queue types in
//! `ehactl-types`; bounded reads of user input files in `ehactl-input`.
#![deny(missing_docs)]

pub mod clock;
pub mod pacer;

pub use ehactl_types::frames::FrameLog;
pub use ehactl_types::{Measurements, PlantState, Timebase};

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
    /// logger, which writes every frame to the `/can` channel and every queued backend
    /// event to `/events`.
    fn frame_log(&self) -> Option<std::sync::Arc<FrameLog>> {
        None
    }

    /// Backend-specific figures for the run summary (e.g. `bus_load_percent`), as a JSON
    /// object whose keys are added to the summary. Called once after the loop.
    fn report(&self) -> Option<serde_json::Value> {
        None
    }
}
