//! # ehactl-canopen
//!
//! The CANopen hardware backend of ehactl:
//! - [`frame`]: fixed-size [`CanFrame`],
//! - [`bus`]: the [`CanBus`] transport trait and bus addresses, with the implementations
//!   [`socketcand`] (rawmode over TCP, pure std) and [`socketcan_bus`] (Linux SocketCAN,
//!   cargo feature `socketcan`),
//! - [`hub`]: the socketcand-compatible relay behind `ehactl canbus hub`,
#![deny(missing_docs)]

pub mod bus;
pub mod frame;
pub mod hub;
pub mod socketcan_bus;
pub mod socketcand;

pub use bus::{BusError, BusErrorKind, BusUrl, CanBus};
pub use frame::{CanFrame, Direction};
