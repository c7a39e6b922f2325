//! The diagnosis side of each catalogue effect, one module per effect: its free parameters
//! with seeds and bounds ([`EffectFit::params`]), its structural variants
//! ([`EffectFit::variants`], DIAGNOSIS.md "Effect variants"), its evidence score from the
//! residual analysis ([`EffectFit::prior`]) and how the synthetic generator
//! hides it in a record ([`EffectFit::hide`], [`EffectFit::hide_variant`]). [`of`] is the one
//! table keyed by [`EffectId`]; `crate::fit::effect_params` / `effect_variants` and
//! `crate::synth::hide` / `hide_variant` look the effect up there.
//!
//! Adding an effect on the diagnosis side: one module here implementing [`EffectFit`] and its
//! line in [`of`] (the match is exhaustive, so a new [`EffectId`] does not build without it).
//! The plant side is the module of the same name in crates/plant/src/effects/ (the effect's
//! config section, checks, own physics and derived constants; its registration in that
//! directory's mod.rs) and the effect's terms in the state equations, in
//! crates/plant/src/model.rs.

use crate::evidence::Analysis;
use crate::freeparam::{FreeParam, Scales};
use crate::rng::Rng;
use ehactl_plant::{EffectId, PlantParams};

pub mod bulk_modulus_pressure;
pub mod flexible_mount;
pub mod friction;
pub mod leakage;
pub mod line_dynamics;
pub mod sensor_tone;
pub mod supply_pressure_drop;
pub mod time_delay;
pub mod valve_deadband;
pub mod valve_dynamics;
pub mod valve_saturation;

/// What the diagnosis needs of one catalogue effect.
pub trait EffectFit: Sync {
    /// Free parameters of the effect in its first (or configured) variant (bounds from the rig
    /// scales `sc`, start values from the nominal section if it exists, else from the residual
    /// analysis `an`). `None` when the effect cannot be tested on this record (e.g. a tone with
    /// no line in any residual spectrum).
    fn params(&self, nominal: &PlantParams, sc: &Scales, an: &Analysis) -> Option<Vec<FreeParam>>;

    /// The structural variants to fit, given `first`, the parameters of [`EffectFit::params`]:
    /// variant name (`-` for effects with one form) and its free parameters. When the nominal
    /// config already has the effect, only its configured variant. Default: one form.
    fn variants(
        &self,
        nominal: &PlantParams,
        sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let _ = (nominal, sc);
        vec![("-", first)]
    }

    /// Prior score of the effect (higher = more suspicious) and its evidence, from the residual
    /// analysis `an` of a record sampled at period `dt` (s); shared rules are methods of
    /// [`Analysis`] (`crate::evidence`).
    fn prior(&self, an: &Analysis, dt: f64) -> (f64, String);

    /// Switch the effect on in `p` with parameters drawn from a realistic range for the test
    /// bench (`crate::synth`).
    fn hide(&self, p: &mut PlantParams, rng: &mut Rng);

    /// Switch the effect on in `p` in its structural variant `variant` (one of
    /// `crate::synth::VARIANT_CASES`, else its default as [`EffectFit::hide`]).
    fn hide_variant(&self, variant: &str, p: &mut PlantParams, rng: &mut Rng) {
        let _ = variant;
        self.hide(p, rng)
    }
}

/// The diagnosis side of catalogue effect `e`: the registration table.
pub fn of(e: EffectId) -> &'static dyn EffectFit {
    match e {
        EffectId::Friction => &friction::Effect,
        EffectId::ValveDeadband => &valve_deadband::Effect,
        EffectId::ValveSaturation => &valve_saturation::Effect,
        EffectId::ValveDynamics => &valve_dynamics::Effect,
        EffectId::InternalLeakage => &leakage::Internal,
        EffectId::ExternalLeakage => &leakage::External,
        EffectId::BulkModulusPressure => &bulk_modulus_pressure::Effect,
        EffectId::LineDynamics => &line_dynamics::Effect,
        EffectId::FlexibleMount => &flexible_mount::Effect,
        EffectId::TimeDelay => &time_delay::Effect,
        EffectId::SensorTone => &sensor_tone::Effect,
        EffectId::SupplyPressureDrop => &supply_pressure_drop::Effect,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each registered module hides its own effect and no other (a wrong line in [`of`]
    /// would hide, fit and score one effect under another's name).
    #[test]
    fn each_effect_hides_itself_only() {
        let base = crate::synth::testrig().plant;
        for e in EffectId::ALL {
            for variant in ["", "lugre", "hose"] {
                let mut p = base.clone();
                p.effects = Default::default();
                of(e).hide_variant(variant, &mut p, &mut Rng::new(1));
                for o in EffectId::ALL {
                    assert_eq!(p.effects.is_enabled(o), o == e, "{e} {variant:?} hid {o}");
                }
            }
        }
    }
}
