//! # ehactl-hal
//!
//! The hardware abstraction of ehactl, in the manner of ros2_control's hardware interface:
//! one [`Hal`] trait with `read(time, period)` / `write(time, period)` called once per
//! cycle. The controller never knows which backend it talks to. This crate holds:
//! - [`Hal`] and its error type, with the lifecycle of a backend (configure / activate /
//!   deactivate, see [`Hal`]),
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

pub use ehactl_types::frames::{CanFrameRecord, FrameLog};
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
    /// The simulated plant reached a finite state no rig can have (a pressure far beyond the
    /// supply, a velocity or force far beyond what the cylinder can produce): a simulation
    /// fault (`ehactl_plant::plausible`).
    Implausible {
        /// Time (s).
        t: f64,
        /// Offending state.
        what: &'static str,
        /// Its value (`unit`).
        value: f64,
        /// The bound it crossed (`unit`).
        bound: f64,
        /// Unit of value and bound.
        unit: &'static str,
    },
    /// A device reported a fault or stopped answering.
    Device {
        /// Device-specific code.
        code: u32,
        /// Short description.
        what: &'static str,
    },
    /// A lifecycle call ([`Hal::configure`], [`Hal::activate`], [`Hal::deactivate`], or a
    /// cycle call [`Hal::read`] / [`Hal::write`]) in a state that does not allow it.
    Lifecycle {
        /// The call (`"configure"`, `"activate"`, `"deactivate"`, `"read"`, `"write"`).
        call: &'static str,
        /// The backend's state at the call (`"unconfigured"`, `"configured"`, `"active"`).
        state: &'static str,
    },
    /// The bring-up of a lifecycle call failed ([`Hal::configure`] or [`Hal::activate`]).
    /// `what` is the phase that failed; the backend keeps the full reason (the CANopen
    /// backend: the start-up error with its frames). A `&'static str` rather than a message
    /// so that `HalError` stays `Copy` and allocation-free for the cycle.
    Startup {
        /// The bring-up phase that failed.
        what: &'static str,
    },
}

/// Why a backend's bring-up ([`Hal::configure`] then [`Hal::activate`]) failed, in full:
/// what [`HalError::Startup`] cannot carry (it is `Copy` for the cycle). Handed over once by
/// [`Hal::take_startup_report`], so that the session logs a failed start-up the same way for
/// every backend without knowing it (the CANopen backend's `StartupFailure`, converted).
#[derive(Debug, Clone, PartialEq)]
pub struct StartupReport {
    /// The reason, one line (e.g. `CANopen start-up: ...`).
    pub reason: String,
    /// What failed to start, as the event channel of the attempt's log (e.g.
    /// `canopen start-up`).
    pub channel: &'static str,
    /// The settings or device files are wrong: nothing reached the hardware, and there is
    /// no attempt to log (the CLI's exit code 2).
    pub settings_error: bool,
    /// The start-up was cut short by a stop request (SIGINT / SIGTERM), not by a fault.
    pub stopped: bool,
    /// Time from the start of the attempt to the failure (s).
    pub elapsed_s: f64,
    /// The time limit that ran out, when the failure is a timeout (s).
    pub time_limit_s: Option<f64>,
    /// Every bus frame sent and received during the attempt, in order; times relative to the
    /// failure (ns, all <= 0).
    pub frames: Vec<CanFrameRecord>,
}

/// The state a call needs: `"configured"` for activate, `"active"` for deactivate, read
/// and write, `"unconfigured"` for configure.
fn expected_state(call: &str) -> &'static str {
    match call {
        "configure" => "unconfigured",
        "activate" => "configured",
        _ => "active",
    }
}

impl HalError {
    /// The state or device concerned (the event channel of a fault).
    pub fn what(&self) -> &'static str {
        match self {
            HalError::Numerical { what, .. }
            | HalError::Implausible { what, .. }
            | HalError::Device { what, .. }
            | HalError::Startup { what } => what,
            HalError::Lifecycle { call, .. } => call,
        }
    }
}

impl std::fmt::Display for HalError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HalError::Numerical { t, what } => {
                write!(f, "plant state `{what}` became non-finite at t = {t} s")
            }
            HalError::Implausible {
                t,
                what,
                value,
                bound,
                unit,
            } => write!(
                f,
                "plant state `{what}` = {value:e} {unit} at t = {t} s is beyond what the rig can reach (bound {bound:e} {unit}): a simulation fault"
            ),
            HalError::Device { code, what } => write!(f, "device fault {code:#x}: {what}"),
            HalError::Lifecycle { call, state } => write!(
                f,
                "backend lifecycle: `{call}` called in state {state}; it needs state {}",
                expected_state(call)
            ),
            HalError::Startup { what } => write!(f, "backend bring-up failed during {what}"),
        }
    }
}

impl std::error::Error for HalError {}

/// Hardware interface used by the control loop, once per cycle, with the lifecycle of
/// ros2_control's hardware components:
///
/// ```text
///  Unconfigured ──configure──▶ Configured ──activate──▶ Active
///                                  ▲                       │
///                                  └──────deactivate───────┘
/// ```
///
/// - **Unconfigured**: the backend exists, nothing has been done to the hardware (a
///   constructor does no I/O);
/// - **Configured** ([`Hal::configure`]): the devices are reachable and set up, the actuator
///   is not enabled (nothing moves);
/// - **Active** ([`Hal::activate`]): the actuator is enabled and the cyclic exchange runs;
///   only here may the loop call [`Hal::read`] and [`Hal::write`];
/// - [`Hal::deactivate`] brings the valve to the safe command and the actuator out of its
///   enabled state, back to Configured: the normal end of a run;
/// - [`Hal::safe_stop`] is allowed in every state and leaves the valve at the safe command:
///   the fallback on every trip, signal and error (and after a failed deactivate).
///
/// A lifecycle call in the wrong state returns [`HalError::Lifecycle`] and changes nothing.
/// A backend without bring-up (the simulated plant) keeps the default implementations:
/// configure and activate succeed without doing anything, deactivate is
/// [`Hal::safe_stop`]; such a backend has no states to enforce, every call succeeds in any
/// order.
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

    /// Put the actuator in its safe state (valve to `command`, typically 0 V). Allowed in
    /// every lifecycle state; called on a trip, on a signal, on an error and when
    /// [`Hal::deactivate`] failed at the end of a run; may block briefly.
    fn safe_stop(&mut self, command: f64) -> Result<(), HalError>;

    /// Unconfigured → Configured: bring the hardware up to ready, actuator not enabled. May
    /// block (bus I/O, device timeouts). Default: nothing to do, succeeds.
    fn configure(&mut self) -> Result<(), HalError> {
        Ok(())
    }

    /// Configured → Active: enable the actuator and start the cyclic exchange; the next
    /// call is the loop's first [`Hal::read`]. May block. Default: nothing to do, succeeds.
    fn activate(&mut self) -> Result<(), HalError> {
        Ok(())
    }

    /// Active → Configured: valve to `safe_command` (V) and the actuator out of its enabled
    /// state; the end of a run. May block briefly. Default: [`Hal::safe_stop`].
    fn deactivate(&mut self, safe_command: f64) -> Result<(), HalError> {
        self.safe_stop(safe_command)
    }

    /// The full reason of the last failed [`Hal::configure`] / [`Hal::activate`] (one that
    /// returned [`HalError::Startup`]), with the bus frames of the attempt; taken, so a
    /// second call gives `None`. Default: `None` (a backend without bring-up never fails
    /// it).
    fn take_startup_report(&mut self) -> Option<StartupReport> {
        None
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    /// A backend that keeps the defaults and counts its safe stops.
    struct Bare {
        stops: Vec<f64>,
    }

    impl Hal for Bare {
        fn name(&self) -> &'static str {
            "bare"
        }
        fn read(&mut self, t: f64, _period: f64) -> Result<Measurements, HalError> {
            Err(HalError::Numerical { t, what: "unused" })
        }
        fn write(&mut self, _t: f64, _period: f64, _command: f64) -> Result<(), HalError> {
            Ok(())
        }
        fn safe_stop(&mut self, command: f64) -> Result<(), HalError> {
            self.stops.push(command);
            Ok(())
        }
    }

    #[test]
    fn the_default_lifecycle_succeeds_and_deactivate_is_the_safe_stop() {
        let mut b = Bare { stops: Vec::new() };
        b.configure().unwrap();
        b.activate().unwrap();
        assert!(
            b.stops.is_empty(),
            "configure / activate must not stop the valve"
        );
        b.deactivate(0.25).unwrap();
        assert_eq!(b.stops, [0.25]);
    }

    #[test]
    fn a_lifecycle_error_names_the_call_its_state_and_the_state_it_needs() {
        let e = HalError::Lifecycle {
            call: "activate",
            state: "unconfigured",
        };
        assert_eq!(
            e.to_string(),
            "backend lifecycle: `activate` called in state unconfigured; it needs state configured"
        );
        assert_eq!(e.what(), "activate");
        let e = HalError::Lifecycle {
            call: "deactivate",
            state: "configured",
        };
        assert!(e.to_string().ends_with("it needs state active"), "{e}");
        let e = HalError::Lifecycle {
            call: "configure",
            state: "active",
        };
        assert!(
            e.to_string().ends_with("it needs state unconfigured"),
            "{e}"
        );
        let e = HalError::Startup { what: "NMT start" };
        assert_eq!(e.to_string(), "backend bring-up failed during NMT start");
        assert_eq!(e.what(), "NMT start");
    }
}
