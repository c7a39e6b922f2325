//! CiA 406 style linear position transducer (Dindorf 2022 used a magnetostrictive transducer
//! with CANopen): objects and the position / speed scaling.

use crate::pdo::MapEntry;
use crate::profile::{field, DecodeError, PdoDir, Profile, ProfilePdo, ProfileStep};
use ehactl_hal::Measurements;
use ehactl_types::canopen::CanopenConfig;

/// Device type 0x1000 low 16 bits: profile 406.
pub const PROFILE: u16 = 406;
/// Position step setting (UNSIGNED32, nm), sub 1.
pub const POSITION_STEP: u16 = 0x6005;
/// Speed step setting (UNSIGNED32, µm/s in this project's EDS), 0x6005:02: the index of the
/// published CiA DS 406 tables of vendor manuals (Temposonics E-Series CANopen operation
/// manual, table 17: 0x6005 sub 1 position measuring step, sub 2 velocity measuring step;
/// there read-only, velocity in 0.01 mm/s). Not 0x6006 (an earlier version of ehactl).
pub const SPEED_STEP: (u16, u8) = (0x6005, 2);
/// Position value (INTEGER32 here, in position steps), 0x6004: CiA 406 position value of the
/// single-magnet device; 0x6020:01 is the multi-sensor object that the TPDO maps.
pub const POSITION_VALUE: u16 = 0x6004;
/// Position value of magnet 1 (INTEGER32, in position steps), 0x6020:01.
pub const POSITION: u16 = 0x6020;
/// Speed value of magnet 1 (INTEGER16, in speed steps), 0x6030:01.
pub const SPEED: u16 = 0x6030;
/// Cyclic timer (UNSIGNED16, ms; 0 = off).
pub const CYCLIC_TIMER: u16 = 0x6200;

/// TPDO1 mapping: position of magnet 1 (4 bytes).
pub const TPDO1_MAP: [MapEntry; 1] = [MapEntry {
    index: POSITION,
    sub: 1,
    bits: 32,
}];

/// Position (m) from the raw INTEGER32 value and the position step (nm).
#[inline]
pub fn position_m(raw: i32, step_nm: u32) -> f64 {
    f64::from(raw) * f64::from(step_nm) * 1e-9
}

/// Speed (m/s) from the raw INTEGER16 value and the speed step (µm/s).
#[inline]
pub fn speed_m_s(raw: i16, step_um_s: u32) -> f64 {
    f64::from(raw) * f64::from(step_um_s) * 1e-6
}

/// The CiA 406 transducer as a [`Profile`]: position step 0x6005:01, cyclic timer off
/// (position on SYNC only), TPDO1 = position 0x6020:01 → [`Measurements::position`].
pub struct Cia406;

impl Profile for Cia406 {
    fn name(&self) -> &'static str {
        "transducer"
    }

    fn number(&self) -> u16 {
        PROFILE
    }

    fn start_steps(&self, c: &CanopenConfig) -> Vec<ProfileStep> {
        vec![
            ProfileStep::required(
                POSITION_STEP,
                1,
                c.position_step_nm.to_le_bytes().to_vec(),
                "setting the transducer position step 0x6005:01 (canopen.position_step_nm)",
            ),
            ProfileStep::where_listed(
                CYCLIC_TIMER,
                0,
                0u16.to_le_bytes().to_vec(),
                "switching the transducer cyclic timer off (TPDO on SYNC)",
            ),
        ]
    }

    fn pdos(&self, _c: &CanopenConfig) -> Vec<ProfilePdo> {
        vec![ProfilePdo::Map {
            dir: PdoDir::Transmit,
            entries: &TPDO1_MAP,
            what: "the transducer TPDO1 (position 0x6020:01)",
        }]
    }

    fn decode(
        &self,
        c: &CanopenConfig,
        data: &[u8],
        m: &mut Measurements,
    ) -> Result<(), DecodeError> {
        let raw = i32::from_le_bytes(field::<4>(data, 0, 4)?);
        m.position = position_m(raw, c.position_step_nm);
        Ok(())
    }

    fn builtin_eds(&self) -> Option<(&'static str, &'static str)> {
        Some((
            crate::eds::BUILTIN_TRANSDUCER_EDS,
            "built-in ehactl_transducer_406.eds",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_uses_the_configured_steps() {
        // 600 000 steps of 1 µm = 0.6 m (003's y_set).
        assert!((position_m(600_000, 1000) - 0.6).abs() < 1e-12);
        assert!((position_m(-5, 5000) + 25e-6).abs() < 1e-15);
        assert!((speed_m_s(250, 1000) - 0.25).abs() < 1e-12);
        assert_eq!(TPDO1_MAP[0].encode(), 0x6020_0120);
    }

    #[test]
    fn the_profile_decodes_the_position_with_the_configured_step() {
        let c = CanopenConfig {
            position_step_nm: 5000,
            ..CanopenConfig::default()
        };
        let mut m = Measurements::UNMEASURED;
        Cia406
            .decode(&c, &(-120_000i32).to_le_bytes(), &mut m)
            .unwrap();
        assert!((m.position + 0.6).abs() < 1e-12, "{}", m.position);
        assert!(m.spool.is_nan() && m.p_a.is_nan() && m.t.is_nan());
        assert_eq!(Cia406.encode(1.0, 10.0), None);
    }
}
