//! `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V), or an
//! amplifier dead zone ahead of the underlapped spool (variant `amplifier`): the config section
//! [`ValveDeadband`] (`[effects.valve_deadband]`) and its component [`Deadband`], the lap
//! stage ([`LapStage`]) of the valve's edge law (`EdgeLaw` in crates/plant/src/valve.rs): the
//! spool target from the command, and where each metering edge starts to open.

use super::component::{Component, LapStage, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `valve_deadband`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeadbandVariant {
    /// Spool overlap: each metering edge opens only after `overlap` of travel (002, 004).
    #[default]
    Overlap,
    /// Dead zone of the valve amplifier ahead of the (underlapped) spool: spool target =
    /// sign(c)·max(|c| − `deadzone`, 0) with c = u/full scale + `zero_offset` (the
    /// amplifier's dead-band setting of proportional-valve electronics, e.g. Bosch Rexroth
    /// VT-VRPA1 "dead band compensation" set to 0; 004 models it as a command dead zone).
    Amplifier,
}

/// `valve_deadband`: spool overlap (dead zone) and zero offset (002: 42 %, 004: 0.0375 V), or
/// an amplifier dead zone ahead of the spool (variant `amplifier`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadband {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`overlap` or `amplifier`).
    #[serde(default)]
    #[param(
        choice,
        desc = "overlap: spool overlap (default); amplifier: dead zone of the amplifier ahead of the \
         underlapped spool"
    )]
    pub variant: DeadbandVariant,
    /// Amplifier dead zone as a fraction of the full-scale command (-), variant `amplifier`.
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "amplifier dead zone, fraction of the full-scale command (variant amplifier)")]
    pub deadzone: f64,
    /// Overlap per edge as a fraction of full spool travel (-).
    #[serde(default)]
    #[param(unit = "-", range = Within(0.0, 0.95), desc = "overlap per edge, fraction of travel", uncertain(order = 17, to_range_end, role = loop_param))]
    pub overlap: f64,
    /// Zero offset of the spool as a fraction of full travel (-), signed.
    #[serde(default)]
    #[param(unit = "-", range = Within(-0.5, 0.5), desc = "spool zero offset, fraction of travel", uncertain(order = 16, to_range_end, role = loop_param))]
    pub zero_offset: f64,
}

/// The component of `valve_deadband`: where the metering edges open, as fractions of full
/// spool travel (-). Variant `overlap`: the spool's zero offset and its overlap per edge;
/// variant `amplifier`: the amplifier's offset and dead zone on the spool target. Every
/// constant is 0 without the effect (the edges open at the centre, the spool follows the
/// command). Stateless; the plant holds it among its components and the valve's edge law
/// (`EdgeLaw` in crates/plant/src/valve.rs) takes it by reference and calls its
/// [`LapStage`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deadband {
    /// Amplifier dead zone d on the spool target (fraction of the full-scale command).
    deadzone: f64,
    /// Amplifier offset added to the command before the dead zone (fraction).
    command_offset: f64,
    /// Spool zero offset (fraction of travel), variant `overlap`.
    zero_offset: f64,
    /// Overlap per edge (fraction of travel), variant `overlap`.
    overlap: f64,
}

impl Deadband {
    /// The constants of a section (`None`, or `enabled = false`: no dead band); what
    /// [`Component::configure`] derives, for the edge law's users outside the plant.
    pub fn new(section: Option<&ValveDeadband>) -> Self {
        let db = section.filter(|d| d.enabled);
        let amp = db.filter(|d| d.variant == DeadbandVariant::Amplifier);
        let spool = db.filter(|d| d.variant == DeadbandVariant::Overlap);
        Deadband {
            deadzone: amp.map_or(0.0, |d| d.deadzone),
            command_offset: amp.map_or(0.0, |d| d.zero_offset),
            zero_offset: spool.map_or(0.0, |d| d.zero_offset),
            overlap: spool.map_or(0.0, |d| d.overlap),
        }
    }
}

impl Component for Deadband {
    type Section = ValveDeadband;

    /// Each field's range is the registry's (overlap, dead zone and offset within their
    /// bounds); each variant reads only its own fields (`overlap` ignores `deadzone`,
    /// `amplifier` `overlap`): nothing to check across fields.
    fn validate(_s: &ValveDeadband) -> Result<(), ConfigError> {
        Ok(())
    }

    /// [`Deadband::new`].
    fn configure(s: Option<&ValveDeadband>, _setup: &Setup) -> Self {
        Deadband::new(s)
    }

    /// No state.
    fn reset(&mut self) {}
}

impl LapStage for Deadband {
    /// `c`, or through the amplifier's offset and dead zone sign(c')·max(|c'| − d, 0),
    /// c' = c + offset.
    #[inline]
    fn target(&self, c: f64) -> f64 {
        if self.deadzone <= 0.0 && self.command_offset == 0.0 {
            return c;
        }
        let c = c + self.command_offset;
        (c.abs() - self.deadzone).max(0.0).copysign(c)
    }

    /// s − zero offset.
    #[inline]
    fn travel(&self, s: f64) -> f64 {
        s - self.zero_offset
    }

    /// x − overlap.
    #[inline]
    fn lap(&self, x: f64) -> f64 {
        x - self.overlap
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(variant: DeadbandVariant) -> ValveDeadband {
        ValveDeadband {
            enabled: true,
            variant,
            deadzone: 0.1,
            overlap: 0.3,
            zero_offset: 0.02,
        }
    }

    #[test]
    fn absent_or_switched_off_is_the_identity() {
        let mut off = section(DeadbandVariant::Overlap);
        off.enabled = false;
        for d in [
            Deadband::configure(None, &Setup::TEST),
            Deadband::configure(Some(&off), &Setup::TEST),
        ] {
            for x in [-0.7, -0.0, 0.0, 0.25, 1.0] {
                assert_eq!(d.target(x).to_bits(), x.to_bits());
                assert_eq!(d.travel(x).to_bits(), x.to_bits());
                assert_eq!(d.lap(x).to_bits(), x.to_bits());
            }
        }
    }

    #[test]
    fn each_variant_reads_its_own_fields() {
        // Overlap: the spool's offset and lap, the target untouched.
        let d = Deadband::configure(Some(&section(DeadbandVariant::Overlap)), &Setup::TEST);
        assert_eq!(d.target(0.05), 0.05);
        assert_eq!(d.travel(0.5), 0.5 - 0.02);
        assert_eq!(d.lap(0.5), 0.5 - 0.3);
        // Amplifier: sign(c + 0.02)·max(|c + 0.02| − 0.1, 0), no lap.
        let a = Deadband::configure(Some(&section(DeadbandVariant::Amplifier)), &Setup::TEST);
        for (c, want) in [(0.05, 0.0), (-0.11, 0.0), (0.3, 0.22), (-0.5, -0.38)] {
            assert!((a.target(c) - want).abs() < 1e-12, "target({c})");
        }
        assert_eq!((a.travel(0.5), a.lap(0.5)), (0.5, 0.5));
    }
}
