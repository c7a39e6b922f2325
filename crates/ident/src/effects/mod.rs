//! The diagnosis side of each catalogue effect, one module per effect: its free parameters
//! with seeds and bounds ([`EffectFit::params`]), its structural variants
//! ([`EffectFit::variants`], DIAGNOSIS.md "Effect variants"), its evidence score from the
//! residual analysis ([`EffectFit::prior`]). [`of`] is the one table keyed by [`EffectId`];
//! `crate::fit::effect_params` / `effect_variants` and the residual analysis look the effect
//! up there. How the synthetic generator hides each effect in a record is the evaluation
//! harness's (crates/ident-eval/src/hide.rs), not the library's.
//!
//! Adding an effect on the diagnosis side: one module here implementing [`EffectFit`] and its
//! line in [`of`] (the match is exhaustive, so a new [`EffectId`] does not build without it),
//! and its hiding in crates/ident-eval/src/hide.rs (exhaustive as well).
//! The plant side is the module of the same name in crates/plant/src/effects/ (the effect's
//! config section, checks, own physics and derived constants; its registration in that
//! directory's mod.rs) and the effect's terms in the state equations, in
//! crates/plant/src/model.rs.

use crate::evidence::Analysis;
use crate::freeparam::{FreeParam, Scales};
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
