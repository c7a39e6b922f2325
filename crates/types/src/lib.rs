//! # ehactl-types
//!
//! What the plant, the control laws, the logger and the backends share, with no I/O and no
//! physics:
//! - [`spec`], the parameter registry types that `#[derive(Params)]` (crate
//!   `ehactl-params-derive`) generates code against: [`spec::Param`], [`spec::ParamTree`],
//!   ranges, path access and [`spec::ConfigError`] (the checks on a parsed TOML tree are in
//!   `ehactl-config`, crates/config/src/tree.rs, so that this crate compiles no TOML parser),
//! - [`Measurements`], one sample of every sensor (what `Hal::read` returns),
//! - [`PlantState`], the simulated plant's complete state (logged every cycle),
//! - [`event`], the fixed-size events of the supervisor, the pacer and the backends,
//! - [`Timebase`], the control period (built by the config, read by the plant's user, the
//!   pacer, the run loop and the backends),
//! - [`timing::CycleTiming`], what a wall-clock pacer measures of each cycle,
//! - [`queue::LossyQueue`], the one bounded lock-free queue that drops and counts what does
//!   not fit, and on it [`frames`], the queue of raw bus frames and backend events a CAN
//!   backend hands to the logger (`Hal::frame_log`), so that neither compiles the other,
//! - [`canopen`], the `[canopen]` section of the rig config, read by `ehactl-config` and
//!   used by the CANopen backend (`ehactl-canopen`), so that the config does not compile
//!   the CANopen master.
#![deny(missing_docs)]

// The `#[derive(Params)]` expansion names `::ehactl_types::spec`, also inside this crate.
extern crate self as ehactl_types;

pub mod canopen;
pub mod event;
pub mod frames;
pub mod measurements;
pub mod plant_state;
pub mod queue;
pub mod spec;
pub mod timebase;
pub mod timing;

pub use measurements::Measurements;
pub use plant_state::PlantState;
pub use spec::ConfigError;
pub use timebase::Timebase;
