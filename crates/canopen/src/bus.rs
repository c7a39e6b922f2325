//! The [`CanBus`] transport trait, its error type and bus addresses
//! (`socketcan://IFACE`, `socketcand://HOST:PORT/CHANNEL`).

use crate::frame::CanFrame;
use std::time::Duration;

/// What went wrong on a bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BusErrorKind {
    /// The bus address could not be parsed.
    Url,
    /// Could not connect / open the interface.
    Open,
    /// The peer sent something that does not follow the protocol.
    Protocol,
    /// The connection was closed by the peer.
    Closed,
    /// Other I/O failure.
    Io,
    /// Not available on this platform / build.
    Unsupported,
    /// A wait was cut short by a stop request (SIGINT / SIGTERM during start-up).
    Interrupted,
}

/// A transport error with a one-line message naming what was wrong and what was expected.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BusError {
    /// Category.
    pub kind: BusErrorKind,
    /// One-line description.
    pub message: String,
}

impl BusError {
    /// Build an error.
    pub fn new(kind: BusErrorKind, message: impl Into<String>) -> BusError {
        BusError {
            kind,
            message: message.into(),
        }
    }
}

impl std::fmt::Display for BusError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for BusError {}

/// A CAN transport. `send` and `try_recv` never wait for the bus (they may take a
/// syscall); `recv_timeout` waits at most `timeout` and is for work outside the control
/// cycle (start-up, SDO, the I/O threads). The control cycle itself never calls a
/// `CanBus`: it talks to the I/O threads through lock-free queues.
pub trait CanBus: Send {
    /// Queue one frame for transmission.
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError>;
    /// The next received frame if one is already there.
    fn try_recv(&mut self) -> Result<Option<CanFrame>, BusError>;
    /// Wait up to `timeout` for the next frame (`Ok(None)` on timeout).
    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError>;
    /// A second handle on the same bus so that one thread can receive while another sends.
    fn try_clone_bus(&self) -> Result<Box<dyn CanBus>, BusError>;
    /// Human-readable address, e.g. `socketcand://127.0.0.1:29536/can0`.
    fn describe(&self) -> String;
}

/// A parsed bus address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BusUrl {
    /// Linux SocketCAN interface, e.g. `can0`.
    SocketCan {
        /// Interface name.
        iface: String,
    },
    /// socketcand rawmode over TCP.
    Socketcand {
        /// Host name or address.
        host: String,
        /// TCP port.
        port: u16,
        /// CAN channel served by socketcand, e.g. `can0`.
        channel: String,
    },
}

const URL_FORMS: &str = "expected socketcan://IFACE (e.g. socketcan://can0) or socketcand://HOST:PORT/CHANNEL (e.g. socketcand://127.0.0.1:29536/can0)";

fn valid_name(s: &str) -> bool {
    !s.is_empty()
        && s.len() <= 15
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
}

impl BusUrl {
    /// Parse `socketcan://can0` or `socketcand://HOST:PORT/CHANNEL`.
    pub fn parse(s: &str) -> Result<BusUrl, BusError> {
        let err = |m: String| BusError::new(BusErrorKind::Url, format!("bus address `{s}`: {m}"));
        let Some((scheme, rest)) = s.split_once("://") else {
            return Err(err(format!("no scheme; {URL_FORMS}")));
        };
        match scheme {
            "socketcan" => {
                if !valid_name(rest) {
                    return Err(err(format!(
                        "`{rest}` is not a network interface name (1-15 characters of letters, digits, _ - .); {URL_FORMS}"
                    )));
                }
                Ok(BusUrl::SocketCan {
                    iface: rest.to_string(),
                })
            }
            "socketcand" => {
                let Some((hostport, channel)) = rest.split_once('/') else {
                    return Err(err(format!("missing /CHANNEL; {URL_FORMS}")));
                };
                if !valid_name(channel) {
                    return Err(err(format!(
                        "channel `{channel}` is not an interface name (1-15 characters of letters, digits, _ - .)"
                    )));
                }
                let Some((host, port)) = hostport.rsplit_once(':') else {
                    return Err(err(format!("missing :PORT after the host; {URL_FORMS}")));
                };
                let host = host.trim_start_matches('[').trim_end_matches(']');
                if host.is_empty() {
                    return Err(err("empty host".into()));
                }
                let port: u16 = port
                    .parse()
                    .map_err(|_| err(format!("port `{port}` is not a TCP port number 1..65535")))?;
                if port == 0 {
                    return Err(err("port 0 is not a TCP port number 1..65535".into()));
                }
                Ok(BusUrl::Socketcand {
                    host: host.to_string(),
                    port,
                    channel: channel.to_string(),
                })
            }
            other => Err(err(format!("unknown scheme `{other}`; {URL_FORMS}"))),
        }
    }
}

impl std::fmt::Display for BusUrl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BusUrl::SocketCan { iface } => write!(f, "socketcan://{iface}"),
            BusUrl::Socketcand {
                host,
                port,
                channel,
            } => write!(f, "socketcand://{host}:{port}/{channel}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_both_forms() {
        assert_eq!(
            BusUrl::parse("socketcan://can0").unwrap(),
            BusUrl::SocketCan {
                iface: "can0".into()
            }
        );
        assert_eq!(
            BusUrl::parse("socketcand://127.0.0.1:29536/can0").unwrap(),
            BusUrl::Socketcand {
                host: "127.0.0.1".into(),
                port: 29536,
                channel: "can0".into()
            }
        );
        let u = BusUrl::parse("socketcand://[::1]:7/vcan0").unwrap();
        assert_eq!(u.to_string(), "socketcand://::1:7/vcan0");
    }

    #[test]
    fn errors_name_the_problem() {
        let e = |s: &str| BusUrl::parse(s).unwrap_err().message;
        assert!(e("can0").contains("no scheme"));
        assert!(e("tcp://x:1/can0").contains("unknown scheme `tcp`"));
        assert!(e("socketcand://127.0.0.1:29536").contains("missing /CHANNEL"));
        assert!(e("socketcand://127.0.0.1/can0").contains("missing :PORT"));
        assert!(e("socketcand://h:99999/can0").contains("port `99999`"));
        assert!(e("socketcand://h:0/can0").contains("port 0"));
        assert!(e("socketcan://").contains("interface name"));
        assert!(e("socketcand://h:1/").contains("channel ``"));
    }
}
