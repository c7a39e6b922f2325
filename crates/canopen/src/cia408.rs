//! CiA 408 proportional valve with on-board electronics (Dindorf 2022: Rexroth 4WRSE): the
//! device state machine as published (control word / status word bits D, H, M, R), device
//! and control mode, hold setpoint, spool setpoint scaling (±16384 = ±100 % spool).

use crate::pdo::{MapEntry, RPDO1_COMM};
use crate::profile::{field, DecodeError, DeviceState, PdoDir, Profile, ProfilePdo, ProfileStep};
use ehactl_hal::Measurements;
use ehactl_types::canopen::CanopenConfig;

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

/// Control mode (INTEGER8).
pub const CONTROL_MODE: u16 = 0x6043;
/// Spool hold setpoint (INTEGER16), sub 1: the spool position the valve controls to in HOLD
/// and FAULT_HOLD (Moog B99224-DV018 §5.2.1, object 0x6314).
pub const SPOOL_HOLD_SETPOINT: u16 = 0x6314;
/// Control mode 0x6043 = 2: spool position control, closed loop (CiA 408; Moog
/// B99224-DV018 §7.1 "Control modes").
pub const CONTROL_MODE_SPOOL_CLOSED_LOOP: i8 = 2;

// Device state machine of CiA 408 as published by Moog, "Moog ACV with CANopen bus
// interface", B99224-DV018-D-211 Rev. A (2018), §5.2 "Device state machine (DSM)", fig. 19
// and §5.2.2 tables (cross-checked against Beckhoff TF8560 ST_CoE408_StatusWord /
// ST_CoE408_ControlWord: status bit 3 = Ready, control bit 3 = Reset).
// Control word bits: D (0, disable → enable), H (1, hold), M (2, device mode active),
// R (3, reset fault, rising edge). Status word bits: D, H, M, R (3 = Ready, *not* fault).

/// Control word bit 0: D (DISABLED reachable: TR2 for x001).
pub const CW_ENABLE: u16 = 1 << 0;
/// Control word bit 1: H (HOLD: TR3 for x011).
pub const CW_HOLD: u16 = 1 << 1;
/// Control word bit 2: M (ACTIVE: TR4 for x111).
pub const CW_ACTIVE: u16 = 1 << 2;
/// Control word bit 3: R, reset fault; acts on its rising edge with D/H held (TR10, TR11, TR14).
pub const CW_RESET: u16 = 1 << 3;
/// Status word bit 3: R, Ready (set in every non-fault state from INIT on).
pub const SW_READY: u16 = 1 << 3;

/// Control word for INIT (MHD = 000, TR7 from DISABLED).
pub const CW_DISABLED: u16 = 0;
/// Control word for DISABLED (MHD = 001).
pub const CW_DISABLED_STATE: u16 = CW_ENABLE;
/// Control word for HOLD (MHD = 011): the valve controls to the hold setpoint 0x6314.
pub const CW_HOLD_STATE: u16 = CW_ENABLE | CW_HOLD;
/// Control word for ACTIVE (MHD = 111).
pub const CW_ACTIVE_STATE: u16 = CW_ENABLE | CW_HOLD | CW_ACTIVE;

/// Valve device state (status word bits 0..3 = D, H, M, R).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValveState {
    /// RMHD 0000 before boot-up (indistinguishable from FAULT_INIT by the status word).
    NotReady,
    /// RMHD 1000: communication up, device function disabled.
    Init,
    /// RMHD 1001: device function disabled, actual values available (failsafe spool).
    Disabled,
    /// RMHD 1011: control loop active on the hold setpoint 0x6314.
    Hold,
    /// RMHD 1111: setpoint from the bus acts.
    Active,
    /// RMHD 0111: fault detected, vendor fault reaction running (EMCY sent on entry, TR8).
    FaultReaction,
    /// RMHD 0011: after a fault, holding the hold setpoint.
    FaultHold,
    /// RMHD 0001: after a fault, failsafe spool.
    FaultDisabled,
    /// RMHD 0000: after a fault, device function disabled.
    FaultInit,
    /// Any other bit pattern of bits 0..3 (e.g. 0x0C), not a state of the DSM.
    Unknown(u8),
}

impl ValveState {
    /// Decode bits 0..3 of the status word 0x6041 (fig. 19 of B99224-DV018). 0000 is both
    /// NOT_READY and FAULT_INIT; it is reported as FAULT_INIT (a device that has booted is
    /// past NOT_READY, and either way it is no state to run in).
    #[inline]
    pub fn from_status(sw: u16) -> ValveState {
        match (sw & 0x0F) as u8 {
            0b1000 => ValveState::Init,
            0b1001 => ValveState::Disabled,
            0b1011 => ValveState::Hold,
            0b1111 => ValveState::Active,
            0b0111 => ValveState::FaultReaction,
            0b0011 => ValveState::FaultHold,
            0b0001 => ValveState::FaultDisabled,
            0b0000 => ValveState::FaultInit,
            x => ValveState::Unknown(x),
        }
    }

    /// Status word bits 0..3 of the state (RMHD); 0 for `Unknown`.
    pub fn status_bits(self) -> u16 {
        match self {
            ValveState::NotReady | ValveState::FaultInit => 0b0000,
            ValveState::Init => 0b1000,
            ValveState::Disabled => 0b1001,
            ValveState::Hold => 0b1011,
            ValveState::Active => 0b1111,
            ValveState::FaultReaction => 0b0111,
            ValveState::FaultHold => 0b0011,
            ValveState::FaultDisabled => 0b0001,
            ValveState::Unknown(x) => u16::from(x),
        }
    }

    /// One of the fault states (FAULT_REACTION, FAULT_HOLD, FAULT_DISABLED, FAULT_INIT).
    pub fn is_fault(self) -> bool {
        matches!(
            self,
            ValveState::FaultReaction
                | ValveState::FaultHold
                | ValveState::FaultDisabled
                | ValveState::FaultInit
        )
    }

    /// Control word bits MHD that a fault reset of this state must hold while R rises
    /// (TR10: 0001, TR11: 0011, TR14: 0000); None for non-fault states and FAULT_REACTION
    /// (which ends by itself, TR9/TR12/TR13).
    pub fn reset_hold_bits(self) -> Option<u16> {
        match self {
            ValveState::FaultDisabled => Some(CW_DISABLED_STATE),
            ValveState::FaultHold => Some(CW_HOLD_STATE),
            ValveState::FaultInit => Some(CW_DISABLED),
            _ => None,
        }
    }

    /// Name as in the profile.
    pub fn as_str(self) -> &'static str {
        match self {
            ValveState::NotReady => "NOT_READY",
            ValveState::Init => "INIT",
            ValveState::Disabled => "DISABLED",
            ValveState::Hold => "HOLD",
            ValveState::Active => "ACTIVE",
            ValveState::FaultReaction => "FAULT_REACTION",
            ValveState::FaultHold => "FAULT_HOLD",
            ValveState::FaultDisabled => "FAULT_DISABLED",
            ValveState::FaultInit => "FAULT_INIT",
            ValveState::Unknown(_) => "UNKNOWN",
        }
    }
}

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

/// The CiA 408 valve as a [`Profile`]: device mode (setpoint from the bus), control mode
/// (spool position, closed loop), a zero hold and spool setpoint, the RPDO1 deadline where
/// the file has it; RPDO1 = spool setpoint 0x6300:01, TPDO1 = status word + actual spool
/// (or disabled); the walk DISABLED → HOLD → ACTIVE and the safe stop in HOLD (the hold
/// setpoint 0x6314:01 = 0, closed centre). It moves the load, so it must consume ehactl's
/// heartbeat.
pub struct Cia408;

impl Profile for Cia408 {
    fn name(&self) -> &'static str {
        "valve"
    }

    fn number(&self) -> u16 {
        PROFILE
    }

    fn moves_the_load(&self) -> bool {
        true
    }

    fn start_steps(&self, c: &CanopenConfig) -> Vec<ProfileStep> {
        let mut steps = vec![
            ProfileStep::required(
                DEVICE_MODE,
                0,
                vec![MODE_SETPOINT_FROM_BUS],
                "setting the valve device mode 0x6042 = 1 (setpoint from the bus)",
            ),
            ProfileStep::required(
                CONTROL_MODE,
                0,
                vec![CONTROL_MODE_SPOOL_CLOSED_LOOP as u8],
                "setting the valve control mode 0x6043 = 2 (spool position, closed loop)",
            ),
            ProfileStep::required(
                SPOOL_HOLD_SETPOINT,
                1,
                0i16.to_le_bytes().to_vec(),
                "setting the valve hold setpoint 0x6314:01 = 0 (closed centre in HOLD)",
            ),
            ProfileStep::required(
                SPOOL_SETPOINT,
                1,
                0i16.to_le_bytes().to_vec(),
                "zeroing the valve spool setpoint",
            ),
        ];
        if c.valve_rpdo_timeout_ms != 0 {
            // RPDO deadline monitoring (CiA 301 v4.2 7.5.2.35 sub 5): set before the RPDO is
            // re-mapped, so that the re-mapping's enable starts it.
            steps.push(ProfileStep::where_listed(
                RPDO1_COMM,
                5,
                c.valve_rpdo_timeout_ms.to_le_bytes().to_vec(),
                "setting the valve RPDO1 deadline 0x1400:05 (canopen.valve_rpdo_timeout_ms)",
            ));
        }
        steps
    }

    fn required_objects(&self) -> &'static [(u16, u8, &'static str)] {
        &[
            (CONTROL_WORD, 0, "the valve control word 0x6040"),
            (STATUS_WORD, 0, "the valve status word 0x6041"),
        ]
    }

    fn pdos(&self, c: &CanopenConfig) -> Vec<ProfilePdo> {
        let rpdo = ProfilePdo::Map {
            dir: PdoDir::Receive,
            entries: &RPDO1_MAP,
            what: "the valve RPDO1 (spool setpoint 0x6300:01)",
        };
        let tpdo = if c.valve_status_pdo {
            ProfilePdo::Map {
                dir: PdoDir::Transmit,
                entries: &TPDO1_MAP,
                what: "the valve TPDO1 (status word 0x6041 + actual spool 0x6301:01)",
            }
        } else {
            ProfilePdo::Disable {
                dir: PdoDir::Transmit,
                what: "disabling the valve TPDO1 (canopen.valve_status_pdo = false)",
            }
        };
        vec![rpdo, tpdo]
    }

    /// The spool position (fraction of full travel) from TPDO1; the status word is the
    /// backend's to judge (any state but ACTIVE trips, crates/canopen/src/hal.rs).
    fn decode(
        &self,
        _c: &CanopenConfig,
        data: &[u8],
        m: &mut Measurements,
    ) -> Result<(), DecodeError> {
        let raw = i16::from_le_bytes(field::<2>(data, 2, 4)?);
        m.spool = spool_fraction(raw);
        Ok(())
    }

    fn encode(&self, u: f64, full_scale_v: f64) -> Option<[u8; 8]> {
        let mut b = [0u8; 8];
        b[..2].copy_from_slice(&setpoint_from_command(u, full_scale_v).to_le_bytes());
        Some(b)
    }

    fn walk(&self) -> &'static [u16] {
        &[CW_DISABLED_STATE, CW_HOLD_STATE, CW_ACTIVE_STATE]
    }

    fn safe_stop(&self) -> Option<u16> {
        Some(CW_HOLD_STATE)
    }

    fn control_object(&self) -> (u16, u8) {
        (CONTROL_WORD, 0)
    }

    /// The device control state of the status word in TPDO1: ACTIVE is where the setpoint
    /// acts; FAULT_REACTION, a fault state and any other state trip.
    fn tpdo_state(&self, data: &[u8]) -> Option<DeviceState> {
        let sw = u16::from_le_bytes(field::<2>(data, 0, 4).ok()?);
        let st = ValveState::from_status(sw);
        let trip = match st {
            ValveState::Active => None,
            ValveState::FaultReaction => Some("valve reports FAULT_REACTION (status word)"),
            s if s.is_fault() => Some("valve reports a fault state (status word)"),
            _ => Some("valve left ACTIVE (status word)"),
        };
        Some(DeviceState {
            name: st.as_str(),
            word: sw,
            trip,
        })
    }

    fn builtin_eds(&self) -> Option<(&'static str, &'static str)> {
        Some((
            crate::eds::BUILTIN_VALVE_EDS,
            "built-in ehactl_valve_408.eds",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Status word codes RMHD of fig. 19 of Moog B99224-DV018 (typed in from the manual,
    /// not from this module), with bits above 3 set to show they are ignored.
    #[test]
    fn status_word_decodes_the_published_codes() {
        let published: [(u16, ValveState); 8] = [
            (0b1000, ValveState::Init),
            (0b1001, ValveState::Disabled),
            (0b1011, ValveState::Hold),
            (0b1111, ValveState::Active),
            (0b0111, ValveState::FaultReaction),
            (0b0011, ValveState::FaultHold),
            (0b0001, ValveState::FaultDisabled),
            (0b0000, ValveState::FaultInit),
        ];
        for (code, st) in published {
            assert_eq!(ValveState::from_status(code), st, "0x{code:04X}");
            assert_eq!(
                ValveState::from_status(code | 0x0610),
                st,
                "high bits ignored"
            );
            assert_eq!(st.status_bits(), code);
            assert_eq!(st.is_fault(), code & SW_READY == 0);
        }
        // A conforming valve in HOLD (0x000B) is HOLD, not a fault; a
        // FAULT_HOLD (0x0003) is no HOLD and a FAULT_REACTION (0x0007) is no ACTIVE.
        assert_eq!(ValveState::from_status(0x000B), ValveState::Hold);
        assert!(ValveState::from_status(0x0003).is_fault());
        assert!(ValveState::from_status(0x0007).is_fault());
        for code in [
            0b0010u16, 0b0100, 0b0101, 0b0110, 0b1010, 0b1100, 0b1101, 0b1110,
        ] {
            assert_eq!(
                ValveState::from_status(code),
                ValveState::Unknown(code as u8)
            );
        }
        // control words of fig. 19: DISABLED MHD xx1, HOLD x11, ACTIVE 111
        assert_eq!(CW_DISABLED_STATE, 0b001);
        assert_eq!(CW_HOLD_STATE, 0b011);
        assert_eq!(CW_ACTIVE_STATE, 0b111);
        // fault reset: R rises with D/H as in TR10 (0001→1001), TR11 (0011→1011), TR14 (0000→1000)
        assert_eq!(ValveState::FaultDisabled.reset_hold_bits(), Some(0b0001));
        assert_eq!(ValveState::FaultHold.reset_hold_bits(), Some(0b0011));
        assert_eq!(ValveState::FaultInit.reset_hold_bits(), Some(0b0000));
        assert_eq!(ValveState::FaultReaction.reset_hold_bits(), None);
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

    #[test]
    fn the_profile_encodes_a_bounded_setpoint_and_decodes_the_spool() {
        // +12 V on a 10 V full scale asks for +100 % spool, not more; NaN asks for zero.
        let sp =
            |u: f64| i16::from_le_bytes(Cia408.encode(u, 10.0).unwrap()[..2].try_into().unwrap());
        assert_eq!((sp(12.0), sp(-5.0), sp(f64::NAN)), (16384, -8192, 0));
        let mut m = Measurements::UNMEASURED;
        // Status word ACTIVE (RMHD 1111), actual spool −8192 = −50 %.
        let pdo = [0x0F, 0x00, 0x00, 0xE0];
        Cia408
            .decode(&CanopenConfig::default(), &pdo, &mut m)
            .unwrap();
        assert_eq!(m.spool, -0.5);
        assert!(m.position.is_nan());
        // The walk ends where the command acts; the safe stop is the state before it.
        assert_eq!(
            Cia408
                .walk()
                .iter()
                .map(|&cw| cw & 0b111)
                .collect::<Vec<_>>(),
            [0b001, 0b011, 0b111]
        );
        assert_eq!(Cia408.safe_stop(), Some(0b011));
    }
}
