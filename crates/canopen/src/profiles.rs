//! The device profiles ehactl knows: one line each in [`PROFILES`]. A new profile is its
//! module (a type implementing [`crate::profile::Profile`]) and its line here.

use crate::profile::Profile;

/// Every profile ehactl knows.
pub static PROFILES: &[&dyn Profile] = &[
    &crate::cia404::Cia404,
    &crate::cia406::Cia406,
    &crate::cia408::Cia408,
];

/// The profile with CiA number `number` (device type 0x1000 bits 0..15), if ehactl knows it.
pub fn by_number(number: u16) -> Option<&'static dyn Profile> {
    PROFILES.iter().copied().find(|p| p.number() == number)
}

/// The profile a config names (`[[canopen.devices]]` `profile`: `"cia"` and the CiA
/// number, e.g. `"cia404"`), if ehactl knows it.
pub fn by_name(name: &str) -> Option<&'static dyn Profile> {
    let number = name.strip_prefix("cia")?.parse().ok()?;
    by_number(number)
}

/// The names [`by_name`] knows, for messages ("cia404, cia406, cia408").
pub fn names() -> String {
    let v: Vec<String> = PROFILES
        .iter()
        .map(|p| format!("cia{}", p.number()))
        .collect();
    v.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use ehactl_hal::Measurements;
    use ehactl_types::canopen::CanopenConfig;

    #[test]
    fn each_profile_is_registered_once_under_its_number() {
        let mut numbers: Vec<u16> = PROFILES.iter().map(|p| p.number()).collect();
        numbers.sort_unstable();
        assert_eq!(numbers, [404, 406, 408]);
        for n in numbers {
            assert_eq!(by_number(n).map(|p| p.number()), Some(n));
        }
        assert!(by_number(402).is_none());
        assert_eq!(by_name("cia404").map(|p| p.number()), Some(404));
        assert!(by_name("cia402").is_none() && by_name("404").is_none());
        assert_eq!(names(), "cia404, cia406, cia408");
    }

    #[test]
    fn every_profile_has_its_built_in_file_of_its_number() {
        for p in PROFILES {
            let (text, name) = p.builtin_eds().unwrap();
            let eds = crate::eds::Eds::parse(text, name).unwrap();
            let dt = eds.default_number(0x1000, 0, 1).unwrap();
            assert_eq!(dt & 0xFFFF, i128::from(p.number()), "{name}");
        }
    }

    #[test]
    fn only_the_valve_moves_the_load_and_has_a_safe_stop() {
        for p in PROFILES {
            assert_eq!(p.moves_the_load(), p.number() == 408, "{}", p.name());
            assert_eq!(p.safe_stop().is_some(), p.moves_the_load(), "{}", p.name());
            assert_eq!(!p.walk().is_empty(), p.moves_the_load(), "{}", p.name());
        }
    }

    #[test]
    fn a_short_pdo_is_an_error_not_a_panic() {
        let c = CanopenConfig::default();
        for p in PROFILES {
            let mut m = Measurements::UNMEASURED;
            let e = p.decode(&c, &[0x12], &mut m).unwrap_err();
            assert_eq!(e.got, 1, "{}", p.name());
            assert!(e.need > 1, "{}", p.name());
            assert!(m.t.is_nan() && m.position.is_nan() && m.p_a.is_nan());
        }
    }
}
