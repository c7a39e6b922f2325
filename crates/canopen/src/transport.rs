//! Opening a bus by its address: [`open`] picks the transport ([`crate::socketcand`] or
//! [`crate::socketcan_bus`]) for a [`BusUrl`]. Kept apart from [`crate::bus`], which the
//! transports themselves use (the trait and the error type), so that the dependency runs one
//! way: transport → bus, and this module → both.

use crate::bus::{BusError, BusUrl, CanBus};
use std::time::Duration;

/// Open the bus at `url`; `timeout` bounds the connection and handshake.
pub fn open(url: &BusUrl, timeout: Duration) -> Result<Box<dyn CanBus>, BusError> {
    match url {
        BusUrl::Socketcand {
            host,
            port,
            channel,
        } => Ok(Box::new(crate::socketcand::SocketcandBus::connect(
            host, *port, channel, timeout,
        )?)),
        BusUrl::SocketCan { iface } => crate::socketcan_bus::open(iface),
    }
}
