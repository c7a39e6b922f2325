//! # ehactl-control
//!
//! Control laws as pure step functions (copper-rs style): they take measurements, a setpoint
//! and the period, and return a command. No I/O, no clock, no config parsing; the runtime
//! (`ehactl-runtime`) calls them once per cycle.
//! - [`pi`]: PI force control in the ideal form of 004 with anti-windup and limits,
//! - [`pd`]: PD position control, 003 eq. 32, with a derivative filter,
//! - [`setpoint`]: step, ramp, sine, chirp, static + dynamic, random steps,
//! - [`supervisor`]: limits and sensor plausibility, trips to the safe command,
//! - [`controller`]: the law a config selects,
//! - [`cycle`]: the cycle kernel, one plain step from a cycle's measurements to its command
//!   (reference, sensor checks, law, command limit, watches), the loop body that `ehactl
//!   run` and the diagnosis's replay both step.
#![deny(missing_docs)]

pub mod controller;
pub mod cycle;
pub mod pd;
pub mod pi;
pub mod setpoint;
pub mod supervisor;
