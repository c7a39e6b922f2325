//! # ehactl-canopen
//!
//! The CANopen hardware backend of ehactl (docs/canopen.md):
//! - [`frame`]: fixed-size [`CanFrame`] (no heap, `Copy`),
//! - [`bus`]: the [`CanBus`] transport trait and bus addresses, with the implementations
//!   [`socketcand`] (rawmode over TCP, pure std) and [`socketcan_bus`] (Linux SocketCAN,
//!   cargo feature `socketcan`), opened by address with [`transport::open`],
//! - [`hub`]: the socketcand-compatible relay behind `ehactl canbus hub`,
//! - the CANopen master split by CiA 301 service: [`nmt`], [`sync`], [`sdo`], [`pdo`],
//!   [`heartbeat`], [`emcy`]; every process function takes the elapsed time as an argument
//!   (CANopenNode style), so time is injected and the protocol is testable frame by frame,
//! - the device-profile seam [`profile`] (trait [`profile::Profile`], the registry
//!   [`profiles::PROFILES`]) and the profiles [`cia404`] (measuring device, one analogue
//!   input), [`cia406`] (position transducer) and [`cia408`] (valve with OBE),
//! - the `[canopen]` config section and the bus-load check: `ehactl_types::canopen` (read by the
//!   config without the CANopen master),
//! - [`eds`]: EDS / DCF files (CiA 306) that drive the start-up,
//! - [`settings`]: [`settings::CanopenSettings`], what start-up and backend are given,
//! - [`clock`]: the caller's time source ([`clock::Clock`]) of start-up and backend: the
//!   clock module of the hardware contract (`ehactl_hal::clock`, shared with the runtime's
//!   wall-clock pacer), re-exported,
//! - [`startup`]: the start-up in phases (configure: boot, identity, EDS-driven SDO
//!   configuration; activate: NMT start, valve state machine, priming),
//! - [`hal`]: [`hal::CanopenHal`], the `Hal` implementation: I/O threads own the bus, the
//!   control cycle talks to them through lock-free queues.
#![deny(missing_docs)]

pub use ehactl_hal::clock;

pub mod bus;
pub mod cia404;
pub mod cia406;
pub mod cia408;
pub mod eds;
pub mod emcy;
pub mod frame;
pub mod hal;
pub mod heartbeat;
pub mod hub;
pub mod nmt;
pub mod pdo;
pub mod profile;
pub mod profiles;
pub mod sdo;
pub mod settings;
#[cfg(test)]
mod simbus;
pub mod socketcan_bus;
pub mod socketcand;
pub mod startup;
pub mod sync;
pub mod transport;

pub use bus::{BusError, BusErrorKind, BusUrl, CanBus};
pub use ehactl_types::canopen::CanopenConfig;
pub use frame::{CanFrame, Direction};
