//! # ehactl-hal
//!
//! The hardware abstraction of ehactl, in the manner of ros2_control's hardware interface:
//! one [`Hal`] trait with `read(time, period)` / `write(time, period)` called once per
//! cycle. The controller never knows which backend it talks to. This crate holds:
//! - [`Hal`] and its error type,
//! - [`sim::SimHal`], the in-process nonlinear plant advanced one control period per write,
//! - [`record`], the fixed-size per-cycle records and events, and
//! - [`logger`], the MCAP writer fed through a bounded lock-free queue from another thread.
#![deny(missing_docs)]

pub mod logger;
pub mod record;
pub mod recover;
pub mod schemas;
pub mod sim;

pub use ehactl_plant::{Measurements, PlantState};

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

    /// Read every sensor at the start of the cycle at time `t` (s); `period` is the
    /// control period (s). Real-time safe: no allocation, no lock, no blocking I/O.
    fn read(&mut self, t: f64, period: f64) -> Result<Measurements, HalError>;

    /// Write the valve command `command` (V), held for `period` (s) from `t`. The
    /// simulation backend advances the plant by one period here. Real-time safe.
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
    fn frame_log(&self) -> Option<std::sync::Arc<logger::FrameLog>> {
        None
    }

    /// Backend-specific figures for the run summary (e.g. `bus_load_percent`), as a JSON
    /// object whose keys are added to the summary. Called once after the loop.
    fn report(&self) -> Option<serde_json::Value> {
        None
    }
}
