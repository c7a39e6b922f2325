//! `internal_leakage` (cross-piston) / `external_leakage` (per chamber to tank): laminar
//! leakage Q = k_l·Δp; external leakage equal or per chamber (variant `per_chamber`). Model
//! and sources: `Leakage` in crates/plant/src/effects/leakage.rs. One module for both: one section type
//! and one seed rule.
//!
//! Seed: k_l = 1 % of the rig's Q/p_s (bounds 10⁻⁵…1×).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{Leakage, LeakageVariant};
use ehactl_plant::{EffectId, PlantParams};

/// The experiment that separates internal from external leakage.
const LEAKAGE_EXPERIMENT: &str = "hold the piston against an end stop and step the command: internal leakage equalises p_a and p_b, external leakage lowers both towards tank";

/// The catalogue effect `internal_leakage`.
pub struct Internal;

impl EffectFit for Internal {
    fn signature(&self) -> Signature {
        Signature::Other
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::ExternalLeakage).then_some(LEAKAGE_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        leakage_prior(an)
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, _an: &Analysis) -> Option<Vec<FreeParam>> {
        Some(leakage_params(EffectId::InternalLeakage, nominal, sc))
    }
}

/// The catalogue effect `external_leakage`.
pub struct External;

impl EffectFit for External {
    fn signature(&self) -> Signature {
        Signature::Other
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::InternalLeakage).then_some(LEAKAGE_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        leakage_prior(an)
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, _an: &Analysis) -> Option<Vec<FreeParam>> {
        Some(leakage_params(EffectId::ExternalLeakage, nominal, sc))
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.external_leakage.as_ref().map(|d| d.variant);
        if cur != Some(LeakageVariant::PerChamber) {
            out.push(("equal", first));
        }
        if cur.is_none() || cur == Some(LeakageVariant::PerChamber) {
            let kc = sc.flow / sc.pressure;
            let l0 = ef.external_leakage.as_ref();
            let ia = l0.map_or(0.01 * kc, |l| l.coefficient.max(1e-5 * kc));
            let ib = l0.map_or(0.01 * kc, |l| l.coefficient_b.max(1e-5 * kc));
            let seed = seeded(nominal, |e| {
                e.external_leakage = Some(Leakage {
                    enabled: true,
                    variant: LeakageVariant::PerChamber,
                    coefficient: 0.0,
                    coefficient_b: 0.0,
                })
            });
            let variant = |p: &mut PlantParams| {
                if let Some(l) = p.effects.external_leakage.as_mut() {
                    l.variant = LeakageVariant::PerChamber;
                }
            };
            out.push((
                "per_chamber",
                vec![
                    FreeParam::at_then(
                        "effects.external_leakage.coefficient",
                        (1e-5 * kc, kc, true, ia),
                        &seed,
                        variant,
                    ),
                    FreeParam::at_then(
                        "effects.external_leakage.coefficient_b",
                        (1e-5 * kc, kc, true, ib),
                        &seed,
                        variant,
                    ),
                ],
            ));
        }
        out
    }
}

/// Free parameters of `internal_leakage` or `external_leakage` (`e`) in its first variant.
fn leakage_params(e: EffectId, nominal: &PlantParams, sc: &Scales) -> Vec<FreeParam> {
    let ef = &nominal.effects;
    let at = FreeParam::at;
    let internal = e == EffectId::InternalLeakage;
    let cur = if internal {
        ef.internal_leakage.clone()
    } else {
        ef.external_leakage.clone()
    };
    let kc = sc.flow / sc.pressure;
    let init = cur
        .as_ref()
        .map_or(0.01 * kc, |l| l.coefficient.max(1e-6 * kc));
    let fresh = Leakage {
        enabled: true,
        variant: LeakageVariant::Equal,
        coefficient: init,
        coefficient_b: 0.0,
    };
    let (name, seed) = if internal {
        let s = seeded(nominal, |e| {
            e.internal_leakage.get_or_insert(fresh);
        });
        ("effects.internal_leakage.coefficient", s)
    } else {
        let s = seeded(nominal, |e| {
            e.external_leakage.get_or_insert(fresh);
        });
        ("effects.external_leakage.coefficient", s)
    };
    vec![at(name, (1e-5 * kc, 1.0 * kc, true, init), &seed)]
}

/// Evidence of a leakage: a level shift of the pressure residuals (1 + its share of their RMS).
fn leakage_prior(an: &Analysis) -> (f64, String) {
    let bias_share = an.bias_share;
    (
        1.0 + bias_share.unwrap_or(0.0),
        match bias_share {
            Some(b) => format!(
                "mean pressure residual is {:.0} % of its RMS (a level shift)",
                b * 100.0
            ),
            None => "no pressure measured: judged by the fits alone".into(),
        },
    )
}
