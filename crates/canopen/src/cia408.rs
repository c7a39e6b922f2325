//! CiA 408 style proportional valve with on-board electronics (seed 003: Rexroth 4WRSE):
//! control word / status word device state machine (simplified, see the ICD), spool
//! setpoint scaling (±16384 = ±100 % spool).

use crate::pdo::MapEntry;

/// Device type 0x1000 low 16 bits: profile 408.
pub const PROFILE: u16 = 408;
/// Control word (UNSIGNED16).
pub const CONTROL_WORD: u16 = 0x6040;
/// Status word (UNSIGNED16).
pub const STATUS_WORD: u16 = 0x6041;
/// Device mode (INTEGER8; 1 = setpoint from the bus).
pub const DEVICE_MODE: u16 = 0x6042;
/// Spool position setpoint (INTEGER16), sub 1.
pub const SPOOL_SETPOINT: u16 = 0x6300;
/// Actual spool position (INTEGER16), sub 1.
pub const SPOOL_ACTUAL: u16 = 0x6301;
/// Device mode "setpoint via bus".
pub const MODE_SETPOINT_FROM_BUS: u8 = 1;
/// ±100 % spool in setpoint units.
pub const FULL_SCALE: i32 = 16384;

/// Control word bit 0: D, enable (leave DISABLED).
pub const CW_ENABLE: u16 = 1 << 0;
/// Control word bit 1: H, hold enable.
pub const CW_HOLD: u16 = 1 << 1;
/// Control word bit 2: A, device mode active enable.
pub const CW_ACTIVE: u16 = 1 << 2;
/// Control word bit 3: R, fault reset (rising edge).
pub const CW_RESET: u16 = 1 << 3;

/// Control word for DISABLED.
pub const CW_DISABLED: u16 = 0;
/// Control word for HOLD (D=1, H=1, A=0): closed centre, the safe state.
pub const CW_HOLD_STATE: u16 = CW_ENABLE | CW_HOLD;
/// Control word for ACTIVE (D=1, H=1, A=1).
pub const CW_ACTIVE_STATE: u16 = CW_ENABLE | CW_HOLD | CW_ACTIVE;

/// RPDO1 mapping: spool setpoint (2 bytes).
pub const RPDO1_MAP: [MapEntry; 1] = [MapEntry {
    index: SPOOL_SETPOINT,
    sub: 1,
    bits: 16,
}];
/// TPDO1 mapping: status word + actual spool (4 bytes).
pub const TPDO1_MAP: [MapEntry; 2] = [
    MapEntry {
        index: STATUS_WORD,
        sub: 0,
        bits: 16,
    },
    MapEntry {
        index: SPOOL_ACTUAL,
        sub: 1,
        bits: 16,
    },
];

/// Valve device state (status word bits 0..3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValveState {
    /// 0b000: after power-on, before boot-up.
    NotReady,
    /// 0b001: no setpoint acts, spool at 0.
    Disabled,
    /// 0b011: hold (closed centre).
    Hold,
    /// 0b111: setpoint from the bus acts.
    Active,
    /// Bit 3: fault, spool held at 0.
    Fault,
    /// Any other bit pattern.
    Unknown(u8),
}

impl ValveState {
    /// Decode the status word.
    #[inline]
    pub fn from_status(sw: u16) -> ValveState {
        if sw & 0x08 != 0 {
            return ValveState::Fault;
        }
        match (sw & 0x07) as u8 {
            0b000 => ValveState::NotReady,
            0b001 => ValveState::Disabled,
            0b011 => ValveState::Hold,
            0b111 => ValveState::Active,
            x => ValveState::Unknown(x),
        }
    }

    /// Name.
    pub fn as_str(self) -> &'static str {
        match self {
            ValveState::NotReady => "NOT_READY",
            ValveState::Disabled => "DISABLED",
            ValveState::Hold => "HOLD",
            ValveState::Active => "ACTIVE",
            ValveState::Fault => "FAULT",
            ValveState::Unknown(_) => "UNKNOWN",
        }
    }
}

/// Spool setpoint (INT16, ±16384 = ±100 %) for a valve command `u` (V) with full scale
/// `full_scale` (V, plant.valve.command_full_scale); saturates at ±100 %.
#[inline]
pub fn setpoint_from_command(u: f64, full_scale: f64) -> i16 {
    let s = (u / full_scale * FULL_SCALE as f64).round();
    if s.is_nan() {
        0
    } else {
        s.clamp(-(FULL_SCALE as f64), FULL_SCALE as f64) as i16
    }
}

/// Valve command (V) for a setpoint (inverse of [`setpoint_from_command`]).
#[inline]
pub fn command_from_setpoint(s: i16, full_scale: f64) -> f64 {
    f64::from(s) / FULL_SCALE as f64 * full_scale
}

/// Spool position as a fraction of full travel (−1..1) from the actual value 0x6301:01.
#[inline]
pub fn spool_fraction(raw: i16) -> f64 {
    f64::from(raw) / FULL_SCALE as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_word_decodes_states() {
        assert_eq!(ValveState::from_status(0x0001), ValveState::Disabled);
        assert_eq!(ValveState::from_status(0x0003), ValveState::Hold);
        assert_eq!(ValveState::from_status(0x0007), ValveState::Active);
        assert_eq!(ValveState::from_status(0x0008), ValveState::Fault);
        assert_eq!(ValveState::from_status(0x000F), ValveState::Fault);
        assert_eq!(ValveState::from_status(0x0000), ValveState::NotReady);
        assert_eq!(ValveState::from_status(0x0005), ValveState::Unknown(5));
        assert_eq!(CW_HOLD_STATE, 0x0003);
        assert_eq!(CW_ACTIVE_STATE, 0x0007);
    }

    #[test]
    fn setpoint_scale_round_trips_and_saturates() {
        assert_eq!(setpoint_from_command(10.0, 10.0), 16384);
        assert_eq!(setpoint_from_command(-5.0, 10.0), -8192);
        assert_eq!(setpoint_from_command(25.0, 10.0), 16384);
        assert_eq!(setpoint_from_command(f64::NAN, 10.0), 0);
        let u = 3.3;
        let back = command_from_setpoint(setpoint_from_command(u, 10.0), 10.0);
        assert!((back - u).abs() <= 10.0 / 16384.0 / 2.0 + 1e-12);
        assert_eq!(spool_fraction(-16384), -1.0);
    }
}
