//! SDO client (CiA 301 §7.2.4): expedited and segmented upload / download with abort
//! codes mapped to their CiA 301 meaning. The protocol is a pure state machine
//! ([`SdoClient`]: request frame out, response frame in, elapsed time for the timeout);
//! [`transfer`] drives it on a [`CanBus`] outside the control cycle.

use crate::bus::{BusError, CanBus};
use crate::clock::Clock;
use crate::frame::CanFrame;
use std::time::Duration;

/// COB-ID base of server → client SDO (+ node id).
pub const SDO_TX_BASE: u16 = 0x580;
/// COB-ID base of client → server SDO (+ node id).
pub const SDO_RX_BASE: u16 = 0x600;

/// CiA 301 Table 22: SDO abort codes and their meaning.
pub const ABORT_CODES: &[(u32, &str)] = &[
    (0x0503_0000, "toggle bit not alternated"),
    (0x0504_0000, "SDO protocol timed out"),
    (0x0504_0001, "client/server command specifier not valid or unknown"),
    (0x0504_0002, "invalid block size"),
    (0x0504_0003, "invalid sequence number"),
    (0x0504_0004, "CRC error"),
    (0x0504_0005, "out of memory"),
    (0x0601_0000, "unsupported access to an object"),
    (0x0601_0001, "attempt to read a write only object"),
    (0x0601_0002, "attempt to write a read only object"),
    (0x0602_0000, "object does not exist in the object dictionary"),
    (0x0604_0041, "object cannot be mapped to the PDO"),
    (0x0604_0042, "the number and length of the objects to be mapped would exceed PDO length"),
    (0x0604_0043, "general parameter incompatibility reason"),
    (0x0604_0047, "general internal incompatibility in the device"),
    (0x0606_0000, "access failed due to a hardware error"),
    (0x0607_0010, "data type does not match, length of service parameter does not match"),
    (0x0607_0012, "data type does not match, length of service parameter too high"),
    (0x0607_0013, "data type does not match, length of service parameter too low"),
    (0x0609_0011, "sub-index does not exist"),
    (0x0609_0030, "invalid value for parameter (download only)"),
    (0x0609_0031, "value of parameter written too high (download only)"),
    (0x0609_0032, "value of parameter written too low (download only)"),
    (0x0609_0036, "maximum value is less than minimum value"),
    (0x060A_0023, "resource not available: SDO connection"),
    (0x0800_0000, "general error"),
    (0x0800_0020, "data cannot be transferred or stored to the application"),
    (0x0800_0021, "data cannot be transferred or stored to the application because of local control"),
    (0x0800_0022, "data cannot be transferred or stored to the application because of the present device state"),
    (0x0800_0023, "object dictionary dynamic generation fails or no object dictionary is present"),
    (0x0800_0024, "no data available"),
];

/// Meaning of an abort code (CiA 301 Table 22), or "unknown abort code".
pub fn abort_meaning(code: u32) -> &'static str {
    ABORT_CODES
        .iter()
        .find(|(c, _)| *c == code)
        .map_or("unknown abort code (not in CiA 301 Table 22)", |(_, m)| m)
}

/// Why an SDO transfer failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoError {
    /// The server aborted the transfer.
    Abort {
        /// Node id.
        node: u8,
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// CiA 301 abort code.
        code: u32,
    },
    /// No response within the timeout (the client sent abort 0x05040000).
    Timeout {
        /// Node id.
        node: u8,
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Timeout (ms).
        ms: u64,
    },
    /// The server's response broke the protocol (the client sent an abort with `code`).
    Protocol {
        /// Node id.
        node: u8,
        /// Object index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// Abort code sent by the client.
        code: u32,
        /// What was wrong.
        what: String,
    },
    /// The bus failed.
    Bus(BusError),
}

impl std::fmt::Display for SdoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SdoError::Abort {
                node,
                index,
                sub,
                code,
            } => write!(
                f,
                "SDO abort from node {node} (0x{node:02X}) on 0x{index:04X}:{sub:02X}: code 0x{code:08X} ({})",
                abort_meaning(*code)
            ),
            SdoError::Timeout {
                node,
                index,
                sub,
                ms,
            } => write!(
                f,
                "SDO timeout: node {node} (0x{node:02X}) did not answer on 0x{index:04X}:{sub:02X} within {ms} ms (canopen.sdo_timeout_ms)"
            ),
            SdoError::Protocol {
                node,
                index,
                sub,
                code,
                what,
            } => write!(
                f,
                "SDO protocol error with node {node} (0x{node:02X}) on 0x{index:04X}:{sub:02X}: {what}; aborted with 0x{code:08X} ({})",
                abort_meaning(*code)
            ),
            SdoError::Bus(e) => write!(f, "SDO transfer failed: {e}"),
        }
    }
}

impl std::error::Error for SdoError {}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    DownloadInitiate,
    DownloadSegment,
    UploadInitiate,
    UploadSegment,
}

/// What the client wants after a response.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoStep {
    /// Not for this transfer (other COB-ID); ignore.
    Ignored,
    /// Send this frame and keep waiting.
    Send(CanFrame),
    /// Transfer complete (uploaded data in [`SdoClient::data`]).
    Done,
    /// Transfer failed; send `abort` if present.
    Failed(SdoError, Option<CanFrame>),
}

/// SDO client for one server node. One transfer at a time.
#[derive(Debug, Clone)]
pub struct SdoClient {
    node: u8,
    state: State,
    index: u16,
    sub: u8,
    toggle: bool,
    buf: Vec<u8>,
    pos: usize,
    size: Option<usize>,
    timeout_ns: u64,
    waited_ns: u64,
}

fn mux(cs: u8, index: u16, sub: u8) -> [u8; 8] {
    let i = index.to_le_bytes();
    [cs, i[0], i[1], sub, 0, 0, 0, 0]
}

/// Abort frame client → server for `node` (CiA 301 abort SDO transfer, cs = 0x80).
pub fn abort_frame(node: u8, index: u16, sub: u8, code: u32) -> CanFrame {
    let mut d = mux(0x80, index, sub);
    d[4..8].copy_from_slice(&code.to_le_bytes());
    CanFrame::std(SDO_RX_BASE + u16::from(node), d)
}

impl SdoClient {
    /// Client for server `node` with response timeout `timeout` .
    pub fn new(node: u8, timeout: Duration) -> SdoClient {
        SdoClient {
            node,
            state: State::Idle,
            index: 0,
            sub: 0,
            toggle: false,
            buf: Vec::with_capacity(64),
            pos: 0,
            size: None,
            timeout_ns: timeout.as_nanos() as u64,
            waited_ns: 0,
        }
    }

    fn req(&self, d: [u8; 8]) -> CanFrame {
        CanFrame::std(SDO_RX_BASE + u16::from(self.node), d)
    }

    /// Start writing `data` to `index:sub`; returns the initiate request to send.
    /// Up to 4 bytes go expedited, longer data segmented.
    pub fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> CanFrame {
        self.index = index;
        self.sub = sub;
        self.buf.clear();
        self.buf.extend_from_slice(data);
        self.pos = 0;
        self.toggle = false;
        self.waited_ns = 0;
        let mut d = mux(0x21, index, sub);
        if data.len() <= 4 {
            // ccs=1, e=1, s=1, n = 4 - len.
            d[0] = 0x23 | (((4 - data.len()) as u8) << 2);
            d[4..4 + data.len()].copy_from_slice(data);
            self.pos = data.len();
        } else {
            d[4..8].copy_from_slice(&(data.len() as u32).to_le_bytes());
        }
        self.state = State::DownloadInitiate;
        self.req(d)
    }

    /// Start reading `index:sub`; returns the initiate request to send.
    pub fn upload(&mut self, index: u16, sub: u8) -> CanFrame {
        self.index = index;
        self.sub = sub;
        self.buf.clear();
        self.pos = 0;
        self.size = None;
        self.toggle = false;
        self.waited_ns = 0;
        self.state = State::UploadInitiate;
        self.req(mux(0x40, index, sub))
    }

    /// Uploaded data of the last completed upload.
    pub fn data(&self) -> &[u8] {
        &self.buf
    }

    /// Whether a transfer is in progress.
    pub fn busy(&self) -> bool {
        self.state != State::Idle
    }

    fn fail(&mut self, code: u32, what: String) -> SdoStep {
        self.state = State::Idle;
        SdoStep::Failed(
            SdoError::Protocol {
                node: self.node,
                index: self.index,
                sub: self.sub,
                code,
                what,
            },
            Some(abort_frame(self.node, self.index, self.sub, code)),
        )
    }

    fn next_segment(&mut self) -> CanFrame {
        let left = self.buf.len() - self.pos;
        let n = left.min(7);
        let last = left <= 7;
        let mut d = [0u8; 8];
        // ccs=0, t, n = 7 - bytes, c = last.
        d[0] = (u8::from(self.toggle) << 4) | (((7 - n) as u8) << 1) | u8::from(last);
        d[1..1 + n].copy_from_slice(&self.buf[self.pos..self.pos + n]);
        self.pos += n;
        self.req(d)
    }

    /// Feed a received frame. Frames from other COB-IDs are [`SdoStep::Ignored`].
    pub fn on_frame(&mut self, f: &CanFrame) -> SdoStep {
        if f.extended || f.id != u32::from(SDO_TX_BASE + u16::from(self.node)) || !self.busy() {
            return SdoStep::Ignored;
        }
        self.waited_ns = 0;
        if f.dlc != 8 {
            return self.fail(
                0x0504_0001,
                format!("response {f:?} has DLC {}, SDO frames have 8 bytes", f.dlc),
            );
        }
        let d = f.data;
        let cs = d[0];
        if cs == 0x80 {
            let code = u32::from_le_bytes([d[4], d[5], d[6], d[7]]);
            self.state = State::Idle;
            return SdoStep::Failed(
                SdoError::Abort {
                    node: self.node,
                    index: u16::from_le_bytes([d[1], d[2]]),
                    sub: d[3],
                    code,
                },
                None,
            );
        }
        match self.state {
            State::Idle => SdoStep::Ignored,
            State::DownloadInitiate => self.on_download_initiate(&d),
            State::DownloadSegment => self.on_download_segment(cs),
            State::UploadInitiate => self.on_upload_initiate(&d),
            State::UploadSegment => self.on_upload_segment(&d),
        }
    }

    /// The response names the object of the transfer (multiplexer, bytes 1..4).
    fn same_mux(&self, d: &[u8; 8]) -> bool {
        u16::from_le_bytes([d[1], d[2]]) == self.index && d[3] == self.sub
    }

    /// The initiate download response (0x60): done, or the first segment.
    fn on_download_initiate(&mut self, d: &[u8; 8]) -> SdoStep {
        let cs = d[0];
        if cs != 0x60 {
            return self.fail(
                0x0504_0001,
                format!("expected initiate download response 0x60, got 0x{cs:02X}"),
            );
        }
        if !self.same_mux(d) {
            return self.fail(0x0504_0001, "response names another object".into());
        }
        if self.pos >= self.buf.len() {
            self.state = State::Idle;
            SdoStep::Done
        } else {
            self.state = State::DownloadSegment;
            SdoStep::Send(self.next_segment())
        }
    }

    /// A download segment response (0x2X, toggle alternating): done, or the next segment.
    fn on_download_segment(&mut self, cs: u8) -> SdoStep {
        if cs & 0xE0 != 0x20 {
            return self.fail(
                0x0504_0001,
                format!("expected download segment response 0x2X, got 0x{cs:02X}"),
            );
        }
        if (cs & 0x10 != 0) != self.toggle {
            return self.fail(0x0503_0000, "toggle bit not alternated".into());
        }
        self.toggle = !self.toggle;
        if self.pos >= self.buf.len() {
            self.state = State::Idle;
            SdoStep::Done
        } else {
            SdoStep::Send(self.next_segment())
        }
    }

    /// The initiate upload response (0x4X): an expedited value (done), or the size of a
    /// segmented one (at most 1 MiB) and the first segment request.
    fn on_upload_initiate(&mut self, d: &[u8; 8]) -> SdoStep {
        let cs = d[0];
        if cs & 0xE0 != 0x40 {
            return self.fail(
                0x0504_0001,
                format!("expected initiate upload response 0x4X, got 0x{cs:02X}"),
            );
        }
        if !self.same_mux(d) {
            return self.fail(0x0504_0001, "response names another object".into());
        }
        let e = cs & 0x02 != 0;
        let s = cs & 0x01 != 0;
        if e {
            let n = if s {
                4 - usize::from((cs >> 2) & 0x03)
            } else {
                4
            };
            self.buf.clear();
            self.buf.extend_from_slice(&d[4..4 + n]);
            self.state = State::Idle;
            SdoStep::Done
        } else {
            self.size = s.then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
            if self.size.is_some_and(|n| n > 1 << 20) {
                return self.fail(0x0504_0005, "announced size exceeds 1 MiB".into());
            }
            self.state = State::UploadSegment;
            SdoStep::Send(self.req([0x60, 0, 0, 0, 0, 0, 0, 0]))
        }
    }

    /// An upload segment response (0x0X / 0x1X, toggle alternating): the last one checks
    /// the announced size, any other asks for the next.
    fn on_upload_segment(&mut self, d: &[u8; 8]) -> SdoStep {
        let cs = d[0];
        if cs & 0xE0 != 0x00 {
            return self.fail(
                0x0504_0001,
                format!("expected upload segment response 0x0X/0x1X, got 0x{cs:02X}"),
            );
        }
        if (cs & 0x10 != 0) != self.toggle {
            return self.fail(0x0503_0000, "toggle bit not alternated".into());
        }
        let n = 7 - usize::from((cs >> 1) & 0x07);
        self.buf.extend_from_slice(&d[1..1 + n]);
        self.toggle = !self.toggle;
        if cs & 0x01 != 0 {
            self.state = State::Idle;
            if let Some(size) = self.size {
                if size != self.buf.len() {
                    let got = self.buf.len();
                    return self.fail(
                        0x0607_0010,
                        format!("announced {size} bytes, received {got}"),
                    );
                }
            }
            SdoStep::Done
        } else if self.buf.len() > 1 << 20 {
            self.fail(0x0504_0005, "upload exceeds 1 MiB".into())
        } else {
            let t = u8::from(self.toggle) << 4;
            SdoStep::Send(self.req([0x60 | t, 0, 0, 0, 0, 0, 0, 0]))
        }
    }

    /// Advance the response timer by `elapsed_ns`; on timeout the transfer fails with
    /// the abort frame (0x05040000) to send.
    pub fn process(&mut self, elapsed_ns: u64) -> Option<SdoStep> {
        if !self.busy() {
            return None;
        }
        self.waited_ns = self.waited_ns.saturating_add(elapsed_ns);
        if self.waited_ns >= self.timeout_ns {
            self.state = State::Idle;
            return Some(SdoStep::Failed(
                SdoError::Timeout {
                    node: self.node,
                    index: self.index,
                    sub: self.sub,
                    ms: self.timeout_ns / 1_000_000,
                },
                Some(abort_frame(self.node, self.index, self.sub, 0x0504_0000)),
            ));
        }
        None
    }
}

/// Run one transfer to completion on `bus` (outside the cycle), its timeout counted on
/// `clock`. Frames that are not for this transfer go to `other` (boot-ups, heartbeats, EMCY
/// arriving meanwhile).
pub fn transfer(
    bus: &mut dyn CanBus,
    client: &mut SdoClient,
    first: CanFrame,
    clock: &dyn Clock,
    other: &mut dyn FnMut(&CanFrame, Direction),
) -> Result<(), SdoError> {
    bus.send(&first).map_err(SdoError::Bus)?;
    other(&first, Direction::Tx);
    let mut last = clock.now_ns();
    loop {
        let f = bus
            .recv_timeout(Duration::from_millis(5))
            .map_err(SdoError::Bus)?;
        let now = clock.now_ns();
        let elapsed = now.saturating_sub(last);
        last = now;
        let step = match f {
            Some(f) => {
                other(&f, Direction::Rx);
                match client.on_frame(&f) {
                    SdoStep::Ignored => client.process(elapsed),
                    s => Some(s),
                }
            }
            None => client.process(elapsed),
        };
        match step {
            None | Some(SdoStep::Ignored) => {}
            Some(SdoStep::Send(f)) => {
                bus.send(&f).map_err(SdoError::Bus)?;
                other(&f, Direction::Tx);
            }
            Some(SdoStep::Done) => return Ok(()),
            Some(SdoStep::Failed(e, abort)) => {
                if let Some(a) = abort {
                    let _ = bus.send(&a);
                    other(&a, Direction::Tx);
                }
                return Err(e);
            }
        }
    }
}

use crate::frame::Direction;

#[cfg(test)]
mod tests {
    use super::*;

    const T: Duration = Duration::from_millis(500);

    fn resp(node: u8, d: [u8; 8]) -> CanFrame {
        CanFrame::std(SDO_TX_BASE + u16::from(node), d)
    }

    #[test]
    fn expedited_download_is_byte_exact() {
        // CiA 301 expedited download of UNSIGNED16 20 to 0x1017:00 on node 0x30:
        // 630 [8] 2B 17 10 00 14 00 00 00, server answers 5B0 [8] 60 17 10 00 00 00 00 00.
        let mut c = SdoClient::new(0x30, T);
        let req = c.download(0x1017, 0, &20u16.to_le_bytes());
        assert_eq!(req.id, 0x630);
        assert_eq!(
            req.payload(),
            &[0x2B, 0x17, 0x10, 0x00, 0x14, 0x00, 0x00, 0x00]
        );
        assert_eq!(
            c.on_frame(&resp(0x30, [0x60, 0x17, 0x10, 0, 0, 0, 0, 0])),
            SdoStep::Done
        );
        // 1, 3 and 4 bytes: cs 0x2F, 0x27, 0x23.
        assert_eq!(c.download(0x6042, 0, &[1]).data[0], 0x2F);
        assert_eq!(c.download(0x2000, 1, &[1, 2, 3]).data[0], 0x27);
        let f = c.download(0x1800, 1, &0x8000_01A0u32.to_le_bytes());
        assert_eq!(
            f.payload(),
            &[0x23, 0x00, 0x18, 0x01, 0xA0, 0x01, 0x00, 0x80]
        );
    }

    #[test]
    fn expedited_upload_decodes_sizes() {
        let mut c = SdoClient::new(0x20, T);
        let req = c.upload(0x1000, 0);
        assert_eq!(
            (req.id, req.payload()),
            (0x620, &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0][..])
        );
        // 0x43: e=1, s=1, n=0 → 4 bytes.
        let r = resp(0x20, [0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x01, 0x00]);
        assert_eq!(c.on_frame(&r), SdoStep::Done);
        assert_eq!(c.data(), &[0x96, 0x01, 0x01, 0x00]);
        c.upload(0x6041, 0);
        // 0x4B: n=2 → 2 bytes.
        assert_eq!(
            c.on_frame(&resp(
                0x20,
                [0x4B, 0x41, 0x60, 0x00, 0x07, 0x00, 0xAA, 0xBB]
            )),
            SdoStep::Done
        );
        assert_eq!(c.data(), &[0x07, 0x00]);
    }

    #[test]
    fn segmented_download_and_upload_follow_cia301() {
        let mut c = SdoClient::new(0x30, T);
        let data: Vec<u8> = (1..=10).collect();
        let req = c.download(0x1008, 0, &data);
        // Initiate with size indicated: cs 0x21, size 10.
        assert_eq!(req.payload(), &[0x21, 0x08, 0x10, 0x00, 10, 0, 0, 0]);
        let seg = match c.on_frame(&resp(0x30, [0x60, 0x08, 0x10, 0, 0, 0, 0, 0])) {
            SdoStep::Send(f) => f,
            s => panic!("{s:?}"),
        };
        // First segment: t=0, n=0, c=0 → 0x00 + 7 bytes.
        assert_eq!(seg.payload(), &[0x00, 1, 2, 3, 4, 5, 6, 7]);
        let seg = match c.on_frame(&resp(0x30, [0x20, 0, 0, 0, 0, 0, 0, 0])) {
            SdoStep::Send(f) => f,
            s => panic!("{s:?}"),
        };
        // Last: t=1, n=4 (3 bytes), c=1 → 0x10 | 0x08 | 0x01 = 0x19.
        assert_eq!(seg.payload(), &[0x19, 8, 9, 10, 0, 0, 0, 0]);
        assert_eq!(
            c.on_frame(&resp(0x30, [0x30, 0, 0, 0, 0, 0, 0, 0])),
            SdoStep::Done
        );

        let req = c.upload(0x1008, 0);
        assert_eq!(req.data[0], 0x40);
        let r = c.on_frame(&resp(0x30, [0x41, 0x08, 0x10, 0x00, 9, 0, 0, 0]));
        assert_eq!(
            r,
            SdoStep::Send(CanFrame::std(0x630, [0x60, 0, 0, 0, 0, 0, 0, 0]))
        );
        let r = c.on_frame(&resp(
            0x30,
            [0x00, b'e', b'h', b'a', b'c', b't', b'l', b' '],
        ));
        assert_eq!(
            r,
            SdoStep::Send(CanFrame::std(0x630, [0x70, 0, 0, 0, 0, 0, 0, 0]))
        );
        // t=1, n=5 (2 bytes), c=1 → 0x1B.
        assert_eq!(
            c.on_frame(&resp(0x30, [0x1B, b'v', b'1', 0, 0, 0, 0, 0])),
            SdoStep::Done
        );
        assert_eq!(c.data(), b"ehactl v1");
    }

    #[test]
    fn aborts_carry_their_cia301_meaning() {
        let mut c = SdoClient::new(0x30, T);
        c.download(0x1A00, 0, &[0]);
        let r = c.on_frame(&resp(
            0x30,
            [0x80, 0x00, 0x1A, 0x00, 0x30, 0x00, 0x09, 0x06],
        ));
        let SdoStep::Failed(e, None) = r else {
            panic!("{r:?}")
        };
        assert_eq!(
            e.to_string(),
            "SDO abort from node 48 (0x30) on 0x1A00:00: code 0x06090030 (invalid value for parameter (download only))"
        );
        assert_eq!(
            abort_meaning(0x0602_0000),
            "object does not exist in the object dictionary"
        );
        assert!(abort_meaning(0x1234_5678).starts_with("unknown"));
    }

    #[test]
    fn toggle_errors_timeouts_and_bad_dlc_abort_the_transfer() {
        let mut c = SdoClient::new(0x30, T);
        c.upload(0x1008, 0);
        c.on_frame(&resp(0x30, [0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0]));
        let r = c.on_frame(&resp(0x30, [0x10, 1, 2, 3, 4, 5, 6, 7]));
        let SdoStep::Failed(SdoError::Protocol { code, .. }, Some(a)) = r else {
            panic!("{r:?}")
        };
        assert_eq!(code, 0x0503_0000);
        assert_eq!(
            a.payload(),
            &[0x80, 0x08, 0x10, 0x00, 0x00, 0x00, 0x03, 0x05]
        );

        c.upload(0x6041, 0);
        assert_eq!(c.process(499_000_000), None);
        let r = c.process(1_000_000).unwrap();
        let SdoStep::Failed(SdoError::Timeout { ms: 500, .. }, Some(a)) = r else {
            panic!("{r:?}")
        };
        assert_eq!(&a.payload()[4..], &[0x00, 0x00, 0x04, 0x05]);
        assert!(!c.busy());

        c.upload(0x6041, 0);
        let r = c.on_frame(&CanFrame::std(0x5B0, [0x4B, 0x41, 0x60]));
        assert!(
            matches!(r, SdoStep::Failed(SdoError::Protocol { .. }, Some(_))),
            "{r:?}"
        );
        // Frames of other nodes are ignored.
        c.upload(0x6041, 0);
        assert_eq!(
            c.on_frame(&resp(0x20, [0x4B, 0x41, 0x60, 0, 1, 0, 0, 0])),
            SdoStep::Ignored
        );
    }
}
