//! The diagnosis side of each catalogue effect, one module per effect: its free parameters
//! with seeds and bounds ([`EffectFit::params`]), its structural variants
//! ([`EffectFit::variants`], DIAGNOSIS.md "Effect variants"), its evidence score from the
//! residual analysis ([`EffectFit::prior`]), where its error concentrates
//! ([`EffectFit::signature`]), whether it acts on one measured channel only
//! ([`EffectFit::measurement_only`]) and the experiment that separates it from another
//! effect ([`EffectFit::separates_from`]); all but `variants` without a default body, so a
//! new effect that forgets one does not build. [`of`] is the one table keyed by [`EffectId`];
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

    /// Where in the record the effect's error concentrates, as the residual analysis
    /// measures it (the second look at a weak round winner, `crate::weigh`, compares two
    /// effects there).
    fn signature(&self) -> Signature;

    /// Whether the effect acts on one measured channel only, not through the plant's
    /// dynamics (a tone on one sensor): the search then also judges it on that channel's
    /// error, not only on the channel mean (DIAGNOSIS.md "Acceptance per channel").
    fn measurement_only(&self) -> bool;

    /// The experiment that separates this effect from `other` when the data could not tell
    /// them apart, if this module knows one; [`separating_experiment`] asks both modules of
    /// a pair (so a pair's rule is written in one of them) and falls back to a generic
    /// excitation.
    fn separates_from(&self, other: EffectId) -> Option<&'static str>;
}

/// Where an effect's error concentrates, as the residual analysis measures it
/// ([`crate::evidence::Analysis`]; the reasoning of Sirohi 2003 §5).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Signature {
    /// Large commands (|u| > 70 % of its maximum): a flow or pressure limit, level-dependent.
    Level,
    /// Small commands (|u| < 5 %): a dead band.
    SmallCommand,
    /// Velocity reversals: friction.
    Reversal,
    /// A residual-to-signal spectrum peak: an unmodelled or shifted mode (lines, mount, β).
    Mode,
    /// Not localised by the analysis (delay, spool lag, leakage, tone).
    Other,
}

/// The experiment that separates the three mode effects (pressure-dependent β, line
/// dynamics, a compliant mount) from one another.
pub(crate) const MODE_EXPERIMENT: &str = "frequency responses at two supply pressures and two load masses: a pressure-dependent β moves the resonance with pressure, a compliant mount with the load mass, line modes with neither";

/// Experiment that separates two effects the data could not tell apart: the rule either
/// effect's module states ([`EffectFit::separates_from`]), else an excitation that isolates
/// one of them.
pub fn separating_experiment(a: EffectId, b: EffectId) -> String {
    of(a)
        .separates_from(b)
        .or_else(|| of(b).separates_from(a))
        .map_or_else(
            || format!("an excitation that isolates one of them: steps and sweeps at different amplitudes and pressure levels, logging every available channel ({} vs {})", a.as_str(), b.as_str()),
            str::to_string,
        )
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

    /// A pair's rule does not depend on the order it is asked in: when both modules of a
    /// pair state one, they state the same, and the answer for a pair with a rule is
    /// symmetric (the generic one names the pair in the order asked).
    #[test]
    fn pair_rules_are_symmetric() {
        for &a in EffectId::ALL.iter() {
            for &b in EffectId::ALL.iter() {
                if let (Some(x), Some(y)) = (of(a).separates_from(b), of(b).separates_from(a)) {
                    assert_eq!(x, y, "{} vs {}", a.as_str(), b.as_str());
                }
                if of(a).separates_from(b).is_some() || of(b).separates_from(a).is_some() {
                    assert_eq!(separating_experiment(a, b), separating_experiment(b, a));
                }
            }
        }
    }

    /// The three mode effects share their experiment; a pair with no rule gets the generic
    /// excitation naming both.
    #[test]
    fn mode_pairs_and_the_fallback() {
        use EffectId::*;
        for (a, b) in [
            (BulkModulusPressure, LineDynamics),
            (BulkModulusPressure, FlexibleMount),
            (LineDynamics, FlexibleMount),
        ] {
            assert_eq!(separating_experiment(a, b), MODE_EXPERIMENT);
        }
        let g = separating_experiment(Friction, SensorTone);
        assert!(g.starts_with("an excitation") && g.ends_with("(friction vs sensor_tone)"));
    }

    /// Only the sensor tone acts on one channel alone.
    #[test]
    fn measurement_only_effects() {
        let m: Vec<EffectId> = EffectId::ALL
            .iter()
            .copied()
            .filter(|e| of(*e).measurement_only())
            .collect();
        assert_eq!(m, vec![EffectId::SensorTone]);
    }
}
