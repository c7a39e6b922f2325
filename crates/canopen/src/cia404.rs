//! CiA 404 measuring device with one analogue input (a pressure transmitter): the process
//! value of the analogue input function block and its decimal digits.
//!
//! Objects as in CiA DS 404 V1.2 (CAN in Automation, 2002), §4.2.2 "Analogue input function
//! block" (field value → process value), with the indices and types of a published device's
//! object dictionary (esd, CAN-CBX-THERMO manual C.3034.21 Rev. 1.2, §8.10.7 AI physical unit
//! 0x6131, §8.10.8 AI decimal digits PV 0x6132, §8.10.12 AI process value 0x9130, INTEGER32:
//! "number of decimal places … defined in 0x6132"). The unit 0x6131 (CiA 303-2 coding) is
//! the device's; this profile reads a transmitter whose process value is in Pa (the
//! project's EDS, configs/eds/ehactl_pressure_404.eds) and feeds chamber A's pressure
//! [`Measurements::p_a`].

use crate::pdo::MapEntry;
use crate::profile::{field, DecodeError, PdoDir, Profile, ProfilePdo, ProfileStep};
use ehactl_hal::Measurements;
use ehactl_types::canopen::CanopenConfig;

/// Device type 0x1000 low 16 bits: profile 404.
pub const PROFILE: u16 = 404;
/// AI decimal digits of the process value (UNSIGNED8), sub = channel.
pub const AI_DECIMAL_DIGITS_PV: u16 = 0x6132;
/// AI process value (INTEGER32), sub = channel.
pub const AI_PV: u16 = 0x9130;
/// Decimal digits ehactl sets at start-up: 0, so the process value counts whole Pa
/// (INTEGER32: ±2.1 GPa, far beyond any hydraulic pressure).
pub const DECIMAL_DIGITS: u8 = 0;

/// TPDO1 mapping: process value of channel 1 (4 bytes).
pub const TPDO1_MAP: [MapEntry; 1] = [MapEntry {
    index: AI_PV,
    sub: 1,
    bits: 32,
}];

/// Process value (Pa) of a raw INTEGER32 value with `decimal_digits` fractional digits.
#[inline]
pub fn pressure_pa(raw: i32, decimal_digits: u8) -> f64 {
    f64::from(raw) / 10f64.powi(i32::from(decimal_digits))
}

/// The CiA 404 pressure transmitter as a [`Profile`]: decimal digits 0x6132:01 = 0, TPDO1 =
/// process value 0x9130:01 → [`Measurements::p_a`] (Pa).
pub struct Cia404;

impl Profile for Cia404 {
    fn name(&self) -> &'static str {
        "pressure transmitter"
    }

    fn number(&self) -> u16 {
        PROFILE
    }

    fn start_steps(&self, _c: &CanopenConfig) -> Vec<ProfileStep> {
        vec![ProfileStep::required(
            AI_DECIMAL_DIGITS_PV,
            1,
            vec![DECIMAL_DIGITS],
            "setting the pressure transmitter's decimal digits 0x6132:01 = 0 (process value in Pa)",
        )]
    }

    fn pdos(&self, _c: &CanopenConfig) -> Vec<ProfilePdo> {
        vec![ProfilePdo::Map {
            dir: PdoDir::Transmit,
            entries: &TPDO1_MAP,
            what: "the pressure transmitter TPDO1 (process value 0x9130:01)",
        }]
    }

    fn decode(
        &self,
        _c: &CanopenConfig,
        data: &[u8],
        m: &mut Measurements,
    ) -> Result<(), DecodeError> {
        let raw = i32::from_le_bytes(field::<4>(data, 0, 4)?);
        m.p_a = pressure_pa(raw, DECIMAL_DIGITS);
        Ok(())
    }

    fn builtin_eds(&self) -> Option<(&'static str, &'static str)> {
        Some((
            include_str!("../../../configs/eds/ehactl_pressure_404.eds"),
            "built-in ehactl_pressure_404.eds",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eds::Eds;

    const EDS: &str = include_str!("../../../configs/eds/ehactl_pressure_404.eds");

    #[test]
    fn decimal_digits_scale_the_process_value() {
        // The esd manual's example: 123456 with 3 decimal digits is 123.456 (of the unit).
        assert!((pressure_pa(123_456, 3) - 123.456).abs() < 1e-12);
        assert_eq!(pressure_pa(-25_000_000, 0), -25e6);
        assert_eq!(TPDO1_MAP[0].encode(), 0x9130_0120);
    }

    #[test]
    fn the_profile_feeds_chamber_a_pressure_only() {
        let mut m = Measurements::UNMEASURED;
        let pdo = 21_000_000i32.to_le_bytes();
        Cia404
            .decode(&CanopenConfig::default(), &pdo, &mut m)
            .unwrap();
        assert_eq!(m.p_a, 21e6);
        assert!(m.position.is_nan() && m.p_b.is_nan() && m.spool.is_nan() && m.t.is_nan());
        assert_eq!(Cia404.encode(1.0, 10.0), None);
        assert!(!Cia404.moves_the_load() && Cia404.walk().is_empty());
    }

    #[test]
    fn the_eds_is_a_404_device_with_what_the_profile_maps() {
        let eds = Eds::parse(EDS, "ehactl_pressure_404.eds").unwrap();
        let dt = eds.default_number(0x1000, 0, 64).unwrap();
        assert_eq!(dt & 0xFFFF, i128::from(PROFILE));
        let pv = eds.get(AI_PV, 1).unwrap();
        assert!(pv.pdo_mapping);
        assert_eq!(pv.size(), Some(4));
        assert!(eds.get(AI_DECIMAL_DIGITS_PV, 1).unwrap().access.writable());
        assert_eq!(
            eds.default_number(0x1A00, 1, 64),
            Some(i128::from(TPDO1_MAP[0].encode()))
        );
    }
}
