//! socketcand rawmode protocol (ASCII over TCP, see linux-can/socketcand `doc/protocol.md`)
//! and a pure-std client implementing [`CanBus`].
//!
//! Wire format (what python-can's `socketcand` interface speaks):
//! server greets `< hi >`; client `< open can0 >` → `< ok >`; client `< rawmode >` → `< ok >`;
//! server→client `< frame ID SEC.USEC DATAHEX >` (standard ids 3 hex digits, extended 8,
//! data contiguous hex, empty data keeps the trailing space); client→server
//! `< send ID DLC B0 B1 ... >` (DLC and bytes in hex, space separated).

use crate::bus::{BusError, BusErrorKind, CanBus};
use crate::frame::{CanFrame, MAX_EXTENDED_ID, MAX_STANDARD_ID};
use std::io::{Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::os::fd::AsRawFd;
use std::time::{Duration, Instant};

/// Longest message accepted without its closing `>` (bytes).
pub const MAX_MESSAGE: usize = 256;

/// Splits a byte stream into `< ... >` messages. Reuses one buffer.
#[derive(Debug, Default)]
pub struct Framer {
    buf: Vec<u8>,
    start: usize,
}

impl Framer {
    /// Empty framer.
    pub fn new() -> Framer {
        Framer {
            buf: Vec::with_capacity(4096),
            start: 0,
        }
    }

    /// Append received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start > 0 && self.start == self.buf.len() {
            self.buf.clear();
            self.start = 0;
        } else if self.start > 2048 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete message (text including `<` and `>`), `Ok(None)` if incomplete, or
    /// an error describing junk that was skipped (the framer resynchronises on the next `<`).
    pub fn next_message(&mut self) -> Result<Option<&str>, String> {
        let rest = &self.buf[self.start..];
        // Whitespace between messages (some servers send newlines) is allowed.
        let skip = rest
            .iter()
            .position(|b| !b.is_ascii_whitespace())
            .unwrap_or(rest.len());
        let rest = &rest[skip..];
        self.start += skip;
        if rest.is_empty() {
            return Ok(None);
        }
        if rest[0] != b'<' {
            let junk_len = rest.iter().position(|&b| b == b'<').unwrap_or(rest.len());
            let junk = String::from_utf8_lossy(&rest[..junk_len.min(40)]).into_owned();
            self.start += junk_len;
            return Err(format!(
                "{junk_len} bytes outside < > skipped (`{junk}`); expected a message `< ... >`"
            ));
        }
        match rest.iter().position(|&b| b == b'>') {
            Some(end) => {
                // A second '<' before '>' means the first message was cut.
                if let Some(inner) = rest[1..end].iter().position(|&b| b == b'<') {
                    let junk = String::from_utf8_lossy(&rest[..inner + 1]).into_owned();
                    self.start += inner + 1;
                    return Err(format!(
                        "unterminated message `{junk}` skipped; expected `>` before the next `<`"
                    ));
                }
                let s = self.start;
                self.start += end + 1;
                std::str::from_utf8(&self.buf[s..s + end + 1])
                    .map(Some)
                    .map_err(|_| "message is not ASCII text; skipped".to_string())
            }
            None if rest.len() > MAX_MESSAGE => {
                let n = rest.len();
                self.start += n;
                Err(format!(
                    "{n} bytes without a closing `>` skipped; messages are at most {MAX_MESSAGE} bytes"
                ))
            }
            None => Ok(None),
        }
    }
}

/// Words of a message `< a b c >` (error if the brackets are missing).
pub fn words(msg: &str) -> Result<std::str::SplitAsciiWhitespace<'_>, String> {
    let inner = msg
        .strip_prefix('<')
        .and_then(|m| m.strip_suffix('>'))
        .ok_or_else(|| format!("`{msg}` is not a `< ... >` message"))?;
    Ok(inner.split_ascii_whitespace())
}

fn parse_id(s: &str, msg: &str) -> Result<(u32, bool), String> {
    if s.is_empty() || s.len() > 8 || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!(
            "`{msg}`: CAN id `{s}` is not 1-3 (standard) or 4-8 (extended) hex digits"
        ));
    }
    let id = u32::from_str_radix(s, 16).map_err(|e| format!("`{msg}`: CAN id `{s}`: {e}"))?;
    let ext = s.len() > 3;
    let max = if ext {
        MAX_EXTENDED_ID
    } else {
        MAX_STANDARD_ID
    };
    if id > max {
        return Err(format!(
            "`{msg}`: CAN id 0x{id:X} exceeds 0x{max:X} for a {} id",
            if ext { "29-bit" } else { "11-bit" }
        ));
    }
    Ok((id, ext))
}

/// Parse a client command `< send ID DLC B0 .. >` into a frame.
pub fn parse_send(msg: &str) -> Result<CanFrame, String> {
    let mut w = words(msg)?;
    if w.next() != Some("send") {
        return Err(format!("`{msg}` is not a `< send ID DLC BYTES >` command"));
    }
    let id = w.next().ok_or_else(|| format!("`{msg}`: missing CAN id"))?;
    let (id, extended) = parse_id(id, msg)?;
    let dlc = w.next().ok_or_else(|| format!("`{msg}`: missing DLC"))?;
    let dlc = u8::from_str_radix(dlc, 16)
        .ok()
        .filter(|d| *d <= 8)
        .ok_or_else(|| format!("`{msg}`: DLC `{dlc}` is not a hex number 0..8"))?;
    let mut data = [0u8; 8];
    let mut n = 0usize;
    for b in w {
        if n >= 8 || b.len() > 2 {
            return Err(format!(
                "`{msg}`: data byte `{b}` beyond 8 bytes or longer than 2 hex digits"
            ));
        }
        data[n] = u8::from_str_radix(b, 16)
            .map_err(|_| format!("`{msg}`: data byte `{b}` is not hex"))?;
        n += 1;
    }
    if n != usize::from(dlc) {
        return Err(format!("`{msg}`: DLC {dlc} but {n} data bytes"));
    }
    Ok(CanFrame {
        id,
        dlc,
        data,
        extended,
    })
}

/// Parse a server message `< frame ID SEC.USEC DATAHEX >` into a frame and its time stamp (s).
pub fn parse_frame(msg: &str) -> Result<(CanFrame, f64), String> {
    let mut w = words(msg)?;
    if w.next() != Some("frame") {
        return Err(format!("`{msg}` is not a `< frame ID TIME DATA >` message"));
    }
    let id = w.next().ok_or_else(|| format!("`{msg}`: missing CAN id"))?;
    let (id, extended) = parse_id(id, msg)?;
    let ts = w
        .next()
        .ok_or_else(|| format!("`{msg}`: missing time stamp SEC.USEC"))?;
    let ts: f64 = ts
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| format!("`{msg}`: time stamp `{ts}` is not SEC.USEC"))?;
    let hex = w.next().unwrap_or("");
    if let Some(extra) = w.next() {
        return Err(format!(
            "`{msg}`: unexpected `{extra}` after the data; data must be contiguous hex"
        ));
    }
    if hex.len() % 2 != 0 || hex.len() > 16 {
        return Err(format!(
            "`{msg}`: data `{hex}` must be an even number (0..16) of hex digits"
        ));
    }
    let mut data = [0u8; 8];
    for (i, pair) in hex.as_bytes().chunks(2).enumerate() {
        let s = std::str::from_utf8(pair).unwrap_or("??");
        data[i] =
            u8::from_str_radix(s, 16).map_err(|_| format!("`{msg}`: data `{hex}` is not hex"))?;
    }
    Ok((
        CanFrame {
            id,
            dlc: (hex.len() / 2) as u8,
            data,
            extended,
        },
        ts,
    ))
}

/// Small fixed buffer for formatting messages without heap allocation.
pub struct MsgBuf {
    buf: [u8; 96],
    len: usize,
}

impl Default for MsgBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl MsgBuf {
    /// Empty buffer.
    pub fn new() -> MsgBuf {
        MsgBuf {
            buf: [0; 96],
            len: 0,
        }
    }
    /// The formatted bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
    /// As text.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(self.as_bytes()).unwrap_or("")
    }
}

impl std::fmt::Write for MsgBuf {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let b = s.as_bytes();
        if self.len + b.len() > self.buf.len() {
            return Err(std::fmt::Error);
        }
        self.buf[self.len..self.len + b.len()].copy_from_slice(b);
        self.len += b.len();
        Ok(())
    }
}

fn write_id(out: &mut MsgBuf, f: &CanFrame) {
    use std::fmt::Write as _;
    let _ = if f.extended {
        write!(out, "{:08X}", f.id & MAX_EXTENDED_ID)
    } else {
        write!(out, "{:03X}", f.id & MAX_STANDARD_ID)
    };
}

/// Format `< send ID DLC B0 .. >` (client → server).
pub fn format_send(f: &CanFrame) -> MsgBuf {
    use std::fmt::Write as _;
    let mut out = MsgBuf::new();
    let _ = out.write_str("< send ");
    write_id(&mut out, f);
    let _ = write!(out, " {:X}", f.dlc);
    for b in f.payload() {
        let _ = write!(out, " {b:02X}");
    }
    let _ = out.write_str(" >");
    out
}

/// Format `< frame ID SEC.USEC DATAHEX >` (server → client); `t` is the time stamp (s).
pub fn format_frame(f: &CanFrame, t: Duration) -> MsgBuf {
    use std::fmt::Write as _;
    let mut out = MsgBuf::new();
    let _ = out.write_str("< frame ");
    write_id(&mut out, f);
    let _ = write!(out, " {}.{:06} ", t.as_secs(), t.subsec_micros());
    for b in f.payload() {
        let _ = write!(out, "{b:02X}");
    }
    let _ = out.write_str(" >");
    out
}

/// socketcand rawmode client over TCP (TCP_NODELAY).
pub struct SocketcandBus {
    stream: TcpStream,
    framer: Framer,
    addr: String,
    rbuf: Box<[u8; 4096]>,
}

fn io_err(kind: BusErrorKind, what: &str, e: std::io::Error) -> BusError {
    BusError::new(kind, format!("{what}: {e}"))
}

impl SocketcandBus {
    /// Connect to `host:port`, open `channel` and enter rawmode. `timeout` bounds the
    /// connection and each handshake reply.
    pub fn connect(
        host: &str,
        port: u16,
        channel: &str,
        timeout: Duration,
    ) -> Result<SocketcandBus, BusError> {
        let addr = format!("socketcand://{host}:{port}/{channel}");
        let open_err = |m: String| BusError::new(BusErrorKind::Open, format!("{addr}: {m}"));
        let sa = (host, port)
            .to_socket_addrs()
            .map_err(|e| open_err(format!("cannot resolve host `{host}`: {e}")))?
            .next()
            .ok_or_else(|| open_err(format!("host `{host}` has no address")))?;
        let stream = TcpStream::connect_timeout(&sa, timeout).map_err(|e| {
            open_err(format!(
                "cannot connect ({e}); is `ehactl canbus hub --listen {host}:{port}` or socketcand running?"
            ))
        })?;
        stream
            .set_nodelay(true)
            .map_err(|e| open_err(format!("cannot set TCP_NODELAY: {e}")))?;
        stream
            .set_write_timeout(Some(Duration::from_millis(500)))
            .map_err(|e| open_err(format!("cannot set write timeout: {e}")))?;
        let mut bus = SocketcandBus {
            stream,
            framer: Framer::new(),
            addr: addr.clone(),
            rbuf: Box::new([0; 4096]),
        };
        bus.expect("< hi >", timeout)?;
        bus.write_raw(format!("< open {channel} >").as_bytes())?;
        bus.expect("< ok >", timeout)?;
        bus.write_raw(b"< rawmode >")?;
        bus.expect("< ok >", timeout)?;
        Ok(bus)
    }

    fn write_raw(&mut self, b: &[u8]) -> Result<(), BusError> {
        self.stream.write_all(b).map_err(|e| {
            let kind = match e.kind() {
                std::io::ErrorKind::BrokenPipe
                | std::io::ErrorKind::ConnectionReset
                | std::io::ErrorKind::ConnectionAborted => BusErrorKind::Closed,
                _ => BusErrorKind::Io,
            };
            io_err(kind, &format!("{}: send failed", self.addr), e)
        })
    }

    /// Wait for one handshake message and check it.
    fn expect(&mut self, want: &str, timeout: Duration) -> Result<(), BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            match self.framer.next_message() {
                Ok(Some(m)) => {
                    if m == want {
                        return Ok(());
                    }
                    let m = m.to_string();
                    return Err(BusError::new(
                        BusErrorKind::Protocol,
                        format!("{}: handshake: expected `{want}`, got `{m}`", self.addr),
                    ));
                }
                Ok(None) => {}
                Err(e) => {
                    return Err(BusError::new(
                        BusErrorKind::Protocol,
                        format!("{}: handshake: {e}", self.addr),
                    ))
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(BusError::new(
                    BusErrorKind::Open,
                    format!(
                        "{}: handshake: no `{want}` within {:.1} s",
                        self.addr,
                        timeout.as_secs_f64()
                    ),
                ));
            }
            self.fill(Some(left))?;
        }
    }

    /// One read into the framer. `None` timeout = non-blocking. Returns bytes read (0 = nothing).
    ///
    /// The socket stays blocking: the clone that sends ([`CanBus::try_clone_bus`]) shares its
    /// file status flags, so an `O_NONBLOCK` set here would make its writes fail at once on a
    /// full send buffer instead of waiting up to the write timeout. A non-blocking read is one
    /// `recv` with `MSG_DONTWAIT` (a per-call flag, no std API for it).
    fn fill(&mut self, timeout: Option<Duration>) -> Result<usize, BusError> {
        let got = match timeout {
            None => self.recv_dontwait(),
            Some(t) => {
                self.stream
                    .set_read_timeout(Some(t.max(Duration::from_micros(1))))
                    .map_err(|e| io_err(BusErrorKind::Io, &self.addr, e))?;
                self.stream.read(&mut self.rbuf[..])
            }
        };
        match got {
            Ok(0) => Err(BusError::new(
                BusErrorKind::Closed,
                format!("{}: connection closed by the server", self.addr),
            )),
            Ok(n) => {
                self.framer.push(&self.rbuf[..n]);
                Ok(n)
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                Ok(0)
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(io_err(
                BusErrorKind::Closed,
                &format!("{}: receive failed", self.addr),
                e,
            )),
        }
    }

    /// Reads what is waiting without blocking (`recv` with `MSG_DONTWAIT`).
    fn recv_dontwait(&mut self) -> std::io::Result<usize> {
        // SAFETY: the descriptor is the open socket of `self.stream` (alive for the call);
        // `rbuf` is a valid, writable buffer of `rbuf.len()` bytes.
        let n = unsafe {
            libc::recv(
                self.stream.as_raw_fd(),
                self.rbuf.as_mut_ptr().cast(),
                self.rbuf.len(),
                libc::MSG_DONTWAIT,
            )
        };
        if n < 0 {
            Err(std::io::Error::last_os_error())
        } else {
            Ok(n as usize)
        }
    }

    /// Next parsed frame already in the buffer. Malformed server messages are errors
    /// (`Protocol`) naming the message; the stream stays usable.
    fn next_buffered(&mut self) -> Result<Option<CanFrame>, BusError> {
        loop {
            let msg = match self.framer.next_message() {
                Ok(Some(m)) => m,
                Ok(None) => return Ok(None),
                Err(e) => {
                    return Err(BusError::new(
                        BusErrorKind::Protocol,
                        format!("{}: {e}", self.addr),
                    ))
                }
            };
            if msg.starts_with("< frame ") {
                return parse_frame(msg).map(|(f, _)| Some(f)).map_err(|e| {
                    BusError::new(BusErrorKind::Protocol, format!("{}: {e}", self.addr))
                });
            }
            if msg == "< ok >" || msg == "< echo >" {
                continue;
            }
            let m = msg.to_string();
            return Err(BusError::new(
                BusErrorKind::Protocol,
                format!("{}: unexpected message `{m}` in rawmode", self.addr),
            ));
        }
    }
}

impl CanBus for SocketcandBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let msg = format_send(frame);
        self.write_raw(msg.as_bytes())
    }

    fn try_recv(&mut self) -> Result<Option<CanFrame>, BusError> {
        if let Some(f) = self.next_buffered()? {
            return Ok(Some(f));
        }
        self.fill(None)?;
        self.next_buffered()
    }

    fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(f) = self.next_buffered()? {
                return Ok(Some(f));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.fill(Some(left))?;
        }
    }

    fn try_clone_bus(&self) -> Result<Box<dyn CanBus>, BusError> {
        let stream = self
            .stream
            .try_clone()
            .map_err(|e| io_err(BusErrorKind::Io, &self.addr, e))?;
        Ok(Box::new(SocketcandBus {
            stream,
            framer: Framer::new(),
            addr: self.addr.clone(),
            rbuf: Box::new([0; 4096]),
        }))
    }

    fn describe(&self) -> String {
        self.addr.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_match_python_can_expectations() {
        let sync = CanFrame::std(0x80, []);
        assert_eq!(
            format_frame(&sync, Duration::new(12, 0)).as_str(),
            "< frame 080 12.000000  >"
        );
        let f = CanFrame::std(0x1A0, [0xDE, 0xAD, 0x0B]);
        assert_eq!(
            format_frame(&f, Duration::new(1, 5_000)).as_str(),
            "< frame 1A0 1.000005 DEAD0B >"
        );
        assert_eq!(format_send(&f).as_str(), "< send 1A0 3 DE AD 0B >");
        assert_eq!(format_send(&sync).as_str(), "< send 080 0 >");
    }

    #[test]
    fn parses_python_can_send_including_empty_data() {
        // python-can writes `< send 080 0  >` (two spaces) and one-digit bytes.
        let f = parse_send("< send 080 0  >").unwrap();
        assert_eq!((f.id, f.dlc, f.extended), (0x80, 0, false));
        let f = parse_send("< send 630 8 23 40 60 0 f 0 0 0 >").unwrap();
        assert_eq!(f.payload(), &[0x23, 0x40, 0x60, 0, 0x0F, 0, 0, 0]);
        let f = parse_send("< send 1FFFFFFF 1 ff >").unwrap();
        assert!(f.extended);
    }

    #[test]
    fn malformed_send_errors_name_the_field() {
        let e = |s: &str| parse_send(s).unwrap_err();
        assert!(e("< send 80G 0 >").contains("CAN id `80G`"));
        assert!(e("< send 800 0 >").contains("exceeds 0x7FF"));
        assert!(e("< send 080 9 >").contains("DLC `9`"));
        assert!(e("< send 080 2 01 >").contains("DLC 2 but 1 data bytes"));
        assert!(e("< send 080 1 123 >").contains("data byte `123`"));
        assert!(e("< send 080 >").contains("missing DLC"));
        assert!(e("< open can0 >").contains("not a `< send"));
    }

    #[test]
    fn parses_frames_and_rejects_bad_ones() {
        let (f, t) = parse_frame("< frame 080 12.000000  >").unwrap();
        assert_eq!((f.id, f.dlc, t), (0x80, 0, 12.0));
        let (f, _) = parse_frame("< frame 1B0 1.5 01020304 >").unwrap();
        assert_eq!(f.payload(), &[1, 2, 3, 4]);
        assert!(parse_frame("< frame 1B0 1.5 010 >")
            .unwrap_err()
            .contains("even number"));
        assert!(parse_frame("< frame 1B0 1.5 01 02 >")
            .unwrap_err()
            .contains("contiguous"));
        assert!(parse_frame("< frame 1B0 x 01 >")
            .unwrap_err()
            .contains("time stamp"));
        assert!(parse_frame("< frame 1B0 1.0 00112233445566778899 >").is_err());
    }

    #[test]
    fn framer_splits_joins_and_resynchronises() {
        let mut fr = Framer::new();
        fr.push(b"< hi >< ok ><fra");
        assert_eq!(fr.next_message().unwrap(), Some("< hi >"));
        assert_eq!(fr.next_message().unwrap(), Some("< ok >"));
        assert_eq!(fr.next_message().unwrap(), None);
        fr.push(b"me 080 1.0  >\ngarbage< ok >");
        assert_eq!(fr.next_message().unwrap(), Some("<frame 080 1.0  >"));
        assert!(fr.next_message().unwrap_err().contains("`garbage`"));
        assert_eq!(fr.next_message().unwrap(), Some("< ok >"));
        fr.push(b"< cut < ok >");
        assert!(fr.next_message().unwrap_err().contains("unterminated"));
        assert_eq!(fr.next_message().unwrap(), Some("< ok >"));
        fr.push(&[b'<'; 300]);
        assert!(fr.next_message().is_err());
    }

    /// A socketcand server that answers the rawmode handshake, sends `frames`, and then
    /// holds the connection without reading until the test ends.
    fn handshake_server(frames: &'static [u8]) -> (u16, std::thread::JoinHandle<()>) {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        let t = std::thread::spawn(move || {
            let (mut c, _) = l.accept().unwrap();
            let mut fr = Framer::new();
            let mut buf = [0u8; 256];
            c.write_all(b"< hi >").unwrap();
            for want in ["< open can0 >", "< rawmode >"] {
                let got = loop {
                    if let Some(m) = fr.next_message().unwrap() {
                        break m.to_string();
                    }
                    let n = c.read(&mut buf).unwrap();
                    fr.push(&buf[..n]);
                };
                assert_eq!(got, want, "the client's handshake");
                c.write_all(b"< ok >").unwrap();
            }
            c.write_all(frames).unwrap();
            // hold: the client closes first (read returns 0 then)
            let _ = c.read(&mut buf);
        });
        (port, t)
    }

    #[test]
    fn a_non_blocking_receive_leaves_the_shared_socket_blocking_for_the_sender() {
        // The RX and TX threads own clones of one socket (one open file description, one
        // set of status flags): the sender's 500 ms write timeout only holds while no read
        // has made the socket O_NONBLOCK.
        let (port, server) = handshake_server(b"< frame 123 0.000000 11 >");
        let mut rx =
            SocketcandBus::connect("127.0.0.1", port, "can0", Duration::from_secs(5)).unwrap();
        let tx = rx.try_clone_bus().unwrap();
        let got = rx.recv_timeout(Duration::from_secs(5)).unwrap();
        assert_eq!(got, CanFrame::new(0x123, &[0x11]));
        assert_eq!(rx.try_recv().unwrap(), None, "nothing else was sent");
        // SAFETY: F_GETFL on the open socket of `rx.stream`.
        let flags = unsafe { libc::fcntl(rx.stream.as_raw_fd(), libc::F_GETFL) };
        assert!(flags >= 0);
        assert_eq!(
            flags & libc::O_NONBLOCK,
            0,
            "the socket was left non-blocking"
        );
        drop((rx, tx));
        server.join().unwrap();
    }
}
