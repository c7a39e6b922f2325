//! NMT (CiA 301 §7.2.8.3): node control commands on COB-ID 0x000 and the node states
//! reported by boot-up / heartbeat messages on 0x700 + node id.

use crate::frame::CanFrame;

/// COB-ID of NMT node control.
pub const NMT_COB_ID: u16 = 0x000;
/// Base COB-ID of boot-up / heartbeat (error control), + node id.
pub const HEARTBEAT_BASE: u16 = 0x700;

/// NMT node control command specifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum NmtCommand {
    /// Start remote node → OPERATIONAL.
    Start = 0x01,
    /// Stop remote node → STOPPED.
    Stop = 0x02,
    /// Enter PRE-OPERATIONAL.
    EnterPreOperational = 0x80,
    /// Reset node (application + communication), then boot-up.
    ResetNode = 0x81,
    /// Reset communication, then boot-up.
    ResetCommunication = 0x82,
}

/// The NMT frame commanding `node` (0 = all nodes): `[cs, node]` on 0x000.
#[inline]
pub fn command(cmd: NmtCommand, node: u8) -> CanFrame {
    CanFrame::std(NMT_COB_ID, [cmd as u8, node])
}

/// NMT state as reported in boot-up / heartbeat byte 0 (bit 7 is the node-guarding toggle).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtState {
    /// Boot-up message (0x00).
    BootUp,
    /// STOPPED (0x04).
    Stopped,
    /// OPERATIONAL (0x05).
    Operational,
    /// PRE-OPERATIONAL (0x7F).
    PreOperational,
}

impl NmtState {
    /// Decode the state byte; `None` for a value CiA 301 does not define.
    pub fn from_byte(b: u8) -> Option<NmtState> {
        match b & 0x7F {
            0x00 => Some(NmtState::BootUp),
            0x04 => Some(NmtState::Stopped),
            0x05 => Some(NmtState::Operational),
            0x7F => Some(NmtState::PreOperational),
            _ => None,
        }
    }

    /// Name as in CiA 301.
    pub fn as_str(self) -> &'static str {
        match self {
            NmtState::BootUp => "BOOT-UP",
            NmtState::Stopped => "STOPPED",
            NmtState::Operational => "OPERATIONAL",
            NmtState::PreOperational => "PRE-OPERATIONAL",
        }
    }
}

/// If `f` is a boot-up / heartbeat message, its node id and state byte.
#[inline]
pub fn parse_error_control(f: &CanFrame) -> Option<(u8, u8)> {
    if f.extended || f.id <= u32::from(HEARTBEAT_BASE) || f.id > u32::from(HEARTBEAT_BASE) + 0x7F {
        return None;
    }
    if f.dlc != 1 {
        return None;
    }
    Some(((f.id - u32::from(HEARTBEAT_BASE)) as u8, f.data[0]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_frames_are_byte_exact() {
        // CiA 301: NMT "start remote node" for node 0x30 is 000 [2] 01 30.
        let f = command(NmtCommand::Start, 0x30);
        assert_eq!((f.id, f.payload()), (0x000, &[0x01, 0x30][..]));
        let f = command(NmtCommand::ResetCommunication, 0);
        assert_eq!(f.payload(), &[0x82, 0x00]);
        assert_eq!(
            command(NmtCommand::EnterPreOperational, 0x20).payload(),
            &[0x80, 0x20]
        );
    }

    #[test]
    fn heartbeat_states_decode() {
        let hb = CanFrame::std(0x730, [0x05]);
        assert_eq!(parse_error_control(&hb), Some((0x30, 0x05)));
        assert_eq!(NmtState::from_byte(0x85), Some(NmtState::Operational)); // toggle bit
        assert_eq!(NmtState::from_byte(0x7F), Some(NmtState::PreOperational));
        assert_eq!(NmtState::from_byte(0x00), Some(NmtState::BootUp));
        assert_eq!(NmtState::from_byte(0x03), None);
        assert_eq!(parse_error_control(&CanFrame::std(0x730, [5, 0])), None);
        assert_eq!(parse_error_control(&CanFrame::std(0x700, [5])), None);
    }
}
