//! Linux SocketCAN transport (production path: `ip link set can0 type can bitrate 1000000`
//! then `socketcan://can0`). Built only with the cargo feature `socketcan` on Linux; in
//! other builds [`open`] returns a clear `Unsupported` error instead.

use crate::bus::{BusError, BusErrorKind, CanBus};

#[cfg(all(feature = "socketcan", target_os = "linux"))]
mod imp {
    use super::*;
    use crate::frame::CanFrame;
    use socketcan::{CanSocket, EmbeddedFrame, ExtendedId, Id, Socket, StandardId};
    use std::os::fd::AsFd;
    use std::time::Duration;

    /// A raw CAN socket bound to one interface.
    pub struct SocketCanBus {
        sock: CanSocket,
        iface: String,
        nonblocking: bool,
    }

    fn err(iface: &str, what: &str, e: std::io::Error) -> BusError {
        BusError::new(
            BusErrorKind::Io,
            format!("socketcan://{iface}: {what}: {e}"),
        )
    }

    impl SocketCanBus {
        fn set_nb(&mut self, nb: bool) -> Result<(), BusError> {
            if self.nonblocking != nb {
                self.sock
                    .set_nonblocking(nb)
                    .map_err(|e| err(&self.iface, "set_nonblocking", e))?;
                self.nonblocking = nb;
            }
            Ok(())
        }

        fn convert(f: socketcan::CanFrame) -> Option<CanFrame> {
            match f {
                socketcan::CanFrame::Data(d) => {
                    let (id, extended) = match d.id() {
                        Id::Standard(s) => (u32::from(s.as_raw()), false),
                        Id::Extended(x) => (x.as_raw(), true),
                    };
                    let mut data = [0u8; 8];
                    let p = d.data();
                    let n = p.len().min(8);
                    data[..n].copy_from_slice(&p[..n]);
                    Some(CanFrame {
                        id,
                        dlc: n as u8,
                        data,
                        extended,
                    })
                }
                _ => None,
            }
        }

        fn read(&mut self) -> Result<Option<CanFrame>, BusError> {
            match self.sock.read_frame() {
                Ok(f) => Ok(Self::convert(f)),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) =>
                {
                    Ok(None)
                }
                Err(e) => Err(err(&self.iface, "receive failed", e)),
            }
        }
    }

    impl CanBus for SocketCanBus {
        fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
            let id: Id = if frame.extended {
                ExtendedId::new(frame.id).map(Id::Extended)
            } else {
                StandardId::new(frame.id as u16).map(Id::Standard)
            }
            .ok_or_else(|| {
                BusError::new(
                    BusErrorKind::Protocol,
                    format!("socketcan://{}: invalid id {:#x}", self.iface, frame.id),
                )
            })?;
            let f = socketcan::CanFrame::new(id, frame.payload()).ok_or_else(|| {
                BusError::new(
                    BusErrorKind::Protocol,
                    format!("socketcan://{}: invalid frame {frame:?}", self.iface),
                )
            })?;
            self.set_nb(false)?;
            self.sock
                .write_frame(&f)
                .map_err(|e| err(&self.iface, "send failed", e))
        }

        fn try_recv(&mut self) -> Result<Option<CanFrame>, BusError> {
            self.set_nb(true)?;
            self.read()
        }

        fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
            self.set_nb(false)?;
            self.sock
                .set_read_timeout(timeout.max(Duration::from_micros(1)))
                .map_err(|e| err(&self.iface, "set_read_timeout", e))?;
            self.read()
        }

        fn try_clone_bus(&self) -> Result<Box<dyn CanBus>, BusError> {
            let fd = self
                .sock
                .as_fd()
                .try_clone_to_owned()
                .map_err(|e| err(&self.iface, "cannot duplicate the socket", e))?;
            let sock = CanSocket::from(fd);
            Ok(Box::new(SocketCanBus {
                sock,
                iface: self.iface.clone(),
                nonblocking: self.nonblocking,
            }))
        }

        fn describe(&self) -> String {
            format!("socketcan://{}", self.iface)
        }
    }

    /// Open `iface` (e.g. `can0`).
    pub fn open(iface: &str) -> Result<Box<dyn CanBus>, BusError> {
        let sock = CanSocket::open(iface).map_err(|e| {
            BusError::new(
                BusErrorKind::Open,
                format!(
                    "socketcan://{iface}: cannot open ({e}); does the kernel support AF_CAN and is the interface up (`ip link set {iface} up type can bitrate 1000000`)? Without SocketCAN use socketcand://HOST:PORT/CHANNEL"
                ),
            )
        })?;
        Ok(Box::new(SocketCanBus {
            sock,
            iface: iface.to_string(),
            nonblocking: false,
        }))
    }
}

/// Open a SocketCAN interface.
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub fn open(iface: &str) -> Result<Box<dyn CanBus>, BusError> {
    imp::open(iface)
}

/// Open a SocketCAN interface: not available in this build.
#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
pub fn open(iface: &str) -> Result<Box<dyn CanBus>, BusError> {
    Err(BusError::new(
        BusErrorKind::Unsupported,
        format!(
            "socketcan://{iface}: this ehactl was built without SocketCAN support (needs Linux and `cargo build --features ehactl-canopen/socketcan`); use socketcand://HOST:PORT/CHANNEL instead"
        ),
    ))
}
