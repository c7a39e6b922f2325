//! # ehactl-runtime
//!
//! Everything that runs the control laws of `ehactl-control` against a [`ehactl_hal::Hal`]:
//! - [`runloop`]: the fixed-step loop (read → supervise → control → write → log), started
//!   each cycle by an [`ehactl_hal::pacer::Pacer`] (the trait sits beside `Hal`),
//!   It steps the configured law, `ehactl_control::controller::Controller` (the kernel the
//!   diagnosis's replay steps too), whose gains [`live`] replaces,
//! - [`sim`]: the simulated backend ([`sim::SimHal`], the nonlinear plant behind the
//!   `Hal` trait, one control period per write),
//! - [`realtime`]: the wall-clock pacer (absolute deadlines, SCHED_FIFO, jitter statistics),
//! - [`live`]: gain / setpoint changes while running (handed over at a cycle boundary),
//! - [`control_socket`]: the Unix socket that feeds [`live`] (`ehactl set`),
//! - [`session`]: a complete run (plant or bus backend, loop, MCAP log, summary) as used by
//!   the CLI and the Python bindings.
//!
//! The data flow of one cycle is described in ARCHITECTURE.md.
#![deny(missing_docs)]

pub mod control_socket;
pub mod live;
pub mod realtime;
pub mod runloop;
pub mod session;
pub mod sim;
