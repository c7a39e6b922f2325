//! # ehactl-controller
//!
//! Control laws as pure step functions (copper-rs style), separate from their runtime:
//! - [`pi`]: PI force control in the ideal form of 004 with anti-windup and limits,
//! - [`pd`]: PD position control, 003 eq. 32, with a derivative filter,
//! - [`setpoint`]: step, ramp, sine, chirp, static + dynamic, random steps,
//! - [`supervisor`]: limits and sensor plausibility, trips to the safe command,
//! - [`config`]: the rig config (plant + control + setpoint + supervisor + run + log),
//! - [`runloop`]: the fixed-step loop over any [`ehactl_hal::Hal`],
//! - [`realtime`]: the wall-clock executor (absolute deadlines, SCHED_FIFO, jitter stats),
//! - [`live`]: gain / setpoint changes while running (double buffer, cycle boundary),
//! - [`control_socket`]: the Unix socket that feeds [`live`] (`ehactl set`),
//! - [`session`]: a complete run (plant, loop, MCAP log, summary) as used by the CLI and
//!   the Python bindings.
#![deny(missing_docs)]

pub mod config;
pub mod control_socket;
pub mod live;
pub mod pd;
pub mod pi;
pub mod realtime;
pub mod runloop;
pub mod session;
pub mod setpoint;
pub mod supervisor;

pub use config::RigConfig;
