//! `line_dynamics`: lumped R-L-C segments between the valve ports and the chambers, rigid pipes or
//! compliant hoses (variant `hose`). Model and sources: `LineDynamics` in
//! crates/plant/src/effects/line_dynamics.rs.
//!
//! Seeds: a 1 m pipe of 8 mm bore, two segments (bounds 0.1…15 m, 2…30 mm); a hose 2 m of 10 mm
//! bore with wall compliance 10⁻⁹ 1/Pa and fittings 1 % of p_s/Q.

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, FreeParam, Scales};
use ehactl_plant::params::{LineDynamics, LineVariant};
use ehactl_plant::{EffectId, PlantParams};

/// The catalogue effect `line_dynamics`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Mode
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        match other {
            EffectId::BulkModulusPressure | EffectId::FlexibleMount => Some(super::MODE_EXPERIMENT),
            _ => None,
        }
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        an.mode_prior()
    }

    fn params(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        _an: &Analysis,
    ) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let cur = ef.line_dynamics.clone().unwrap_or(LineDynamics {
            enabled: true,
            length: 1.0,
            diameter: 8e-3,
            segments: 2,
            bulk_modulus: None,
            port_volume: 0.0,
            variant: Default::default(),
            wall_compliance: 0.0,
            resistance: 0.0,
            friction: Default::default(),
        });
        let (l0, d0) = (cur.length, cur.diameter);
        let seed = seeded(nominal, |e| e.line_dynamics = Some(cur));
        Some(vec![
            at("effects.line_dynamics.length", (0.1, 15.0, true, l0), &seed),
            at(
                "effects.line_dynamics.diameter",
                (2e-3, 3e-2, true, d0),
                &seed,
            ),
        ])
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.line_dynamics.as_ref().map(|l| l.variant);
        if cur.is_none() || cur == Some(LineVariant::Pipe) {
            out.push(("pipe", first));
        }
        if cur.is_none() || cur == Some(LineVariant::Hose) {
            out.push(("hose", hose_params(nominal, sc)));
        }
        out
    }
}

/// Free parameters of `line_dynamics` variant `hose`: hose length per side (its volume at the
/// seed's bore), wall compliance (1/β_eff − 1/β, from 10⁻¹¹ 1/Pa, a steel-braided hose, to
/// 3·10⁻⁸ 1/Pa, β_eff ≈ 30 MPa) and the fittings' laminar resistance (bounded by the rig's
/// p_s/Q scale). Two segments: the hose's first wave mode stays represented.
fn hose_params(nominal: &PlantParams, sc: &Scales) -> Vec<FreeParam> {
    let r_s = sc.pressure / sc.flow;
    let cur = nominal.effects.line_dynamics.clone();
    let base = cur.clone().unwrap_or(LineDynamics {
        enabled: true,
        variant: LineVariant::Hose,
        length: 2.0,
        diameter: 10e-3,
        segments: 2,
        bulk_modulus: None,
        port_volume: 0.0,
        friction: Default::default(),
        wall_compliance: 1e-9,
        resistance: 0.01 * r_s,
    });
    let (l0, w0) = (base.length, base.wall_compliance.max(1e-11));
    let res0 = base.resistance.max(1e-4 * r_s);
    let seed = seeded(nominal, |e| e.line_dynamics = Some(base));
    let variant = |p: &mut PlantParams| {
        if let Some(l) = p.effects.line_dynamics.as_mut() {
            l.variant = LineVariant::Hose;
        }
    };
    vec![
        FreeParam::at_then(
            "effects.line_dynamics.length",
            (0.1, 15.0, true, l0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.line_dynamics.wall_compliance",
            (1e-11, 3e-8, true, w0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.line_dynamics.resistance",
            (1e-4 * r_s, 0.3 * r_s, true, res0),
            &seed,
            variant,
        ),
    ]
}
