//! `friction`: Stribeck seal friction with stick, a load-side Coulomb force (variant
//! `load_coulomb`) or LuGre pre-sliding friction (variant `lugre`; Canudas de Wit, Olsson, Åström
//! and Lischinsky 1995, IEEE Trans. Automatic Control 40(3)). Model and sources: `Friction` in
//! crates/plant/src/effects/friction.rs.
//!
//! Seeds: Coulomb level 0.5 % of the rig force scale p_s·A_A (bounds 10⁻⁴…0.1×), breakaway ratio
//! F_s/F_C 1.2, Stribeck velocity 10 mm/s; LuGre bristle stiffness 0.3× the hydraulic stiffness,
//! bristle damping ζ = 0.2 of the critical 2·√(σ₀·m).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, write, FreeParam, Scales};
use ehactl_plant::params::{Friction, FrictionVariant};
use ehactl_plant::{EffectId, PlantParams};

/// The experiment that separates friction from a valve dead band.
pub(crate) const DEADBAND_EXPERIMENT: &str = "slow triangle-wave position moves (velocity reversals at several speeds) with chamber pressures logged: friction shows a pressure jump at each reversal, a dead band a command gap independent of speed";

/// The catalogue effect `friction`.
pub struct Effect;

impl EffectFit for Effect {
    fn signature(&self) -> Signature {
        Signature::Reversal
    }

    fn measurement_only(&self) -> bool {
        false
    }

    fn separates_from(&self, other: EffectId) -> Option<&'static str> {
        (other == EffectId::ValveDeadband).then_some(DEADBAND_EXPERIMENT)
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        let reversal_ratio = an.reversal_ratio;
        (
            reversal_ratio,
            format!("residual RMS within 10 ms of velocity reversals is {reversal_ratio:.2}× the overall RMS"),
        )
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, _an: &Analysis) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let seed = seeded(nominal, |e| {
            e.friction.get_or_insert(Friction {
                enabled: true,
                variant: FrictionVariant::Stribeck,
                static_force: 0.0,
                coulomb_force: 0.0,
                stribeck_velocity: 0.01,
                viscous: 0.0,
                bristle_stiffness: 0.0,
                bristle_damping: 0.0,
            });
        });
        let c0 = ef
            .friction
            .as_ref()
            .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
        let r0 = ef
            .friction
            .as_ref()
            .map_or(1.2, |f| f.static_force / f.coulomb_force.max(1e-9));
        Some(vec![
            // The Coulomb level moves the breakaway force with it (ratio kept by the next).
            FreeParam::at_then(
                "effects.friction.coulomb_force",
                (1e-4 * sc.force, 0.1 * sc.force, true, c0),
                &seed,
                |p| {
                    if let Some(f) = p.effects.friction.as_mut() {
                        f.static_force = f.coulomb_force;
                    }
                },
            ),
            // A ratio, not a declared parameter: the value written is scaled to F_s = ratio·F_C.
            FreeParam::new(
                "effects.friction.static_force/coulomb_force",
                1.0,
                2.5,
                false,
                r0,
                write("effects.friction.static_force", &seed, |p| {
                    if let Some(f) = p.effects.friction.as_mut() {
                        f.static_force *= f.coulomb_force;
                    }
                }),
            ),
            at(
                "effects.friction.stribeck_velocity",
                (1e-3, 0.1, true, 0.01),
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
        let cur = ef.friction.as_ref().map(|f| f.variant);
        if cur.is_none() || cur == Some(FrictionVariant::Stribeck) {
            out.push(("stribeck", first));
        }
        if cur.is_none() || cur == Some(FrictionVariant::Lugre) {
            out.push(("lugre", lugre_params(nominal, sc)));
        }
        if cur.is_none() || cur == Some(FrictionVariant::LoadCoulomb) {
            let c0 = ef
                .friction
                .as_ref()
                .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
            let seed = seeded(nominal, |e| {
                e.friction = Some(Friction {
                    enabled: true,
                    variant: FrictionVariant::LoadCoulomb,
                    static_force: c0,
                    coulomb_force: c0,
                    stribeck_velocity: 0.005,
                    viscous: 0.0,
                    bristle_stiffness: 0.0,
                    bristle_damping: 0.0,
                })
            });
            let variant = |p: &mut PlantParams| {
                if let Some(f) = p.effects.friction.as_mut() {
                    f.variant = FrictionVariant::LoadCoulomb;
                }
            };
            out.push((
                "load_coulomb",
                vec![
                    // No stick: the breakaway force equals the Coulomb force.
                    FreeParam::at_then(
                        "effects.friction.coulomb_force",
                        (1e-4 * sc.force, 0.1 * sc.force, true, c0),
                        &seed,
                        move |p| {
                            variant(p);
                            if let Some(f) = p.effects.friction.as_mut() {
                                f.static_force = f.coulomb_force;
                            }
                        },
                    ),
                    FreeParam::at_then(
                        "effects.friction.stribeck_velocity",
                        (2e-4, 0.05, true, 0.005),
                        &seed,
                        variant,
                    ),
                ],
            ));
        }
        out
    }
}

/// Free parameters of `friction` variant `lugre` (pre-sliding bristles, Canudas de Wit et al.
/// 1995): Coulomb level, breakaway ratio F_s/F_C, Stribeck velocity, bristle stiffness σ₀
/// (bounded by the rig's hydraulic stiffness: 10⁻³…10×) and bristle damping as a ratio ζ of
/// the critical 2·√(σ₀·m) of the moving mass.
fn lugre_params(nominal: &PlantParams, sc: &Scales) -> Vec<FreeParam> {
    let f0 = nominal.effects.friction.clone();
    let c0 = f0
        .as_ref()
        .map_or(0.005 * sc.force, |f| f.coulomb_force.max(1e-3 * sc.force));
    let r0 = f0.as_ref().map_or(1.2, |f| {
        (f.static_force / f.coulomb_force.max(1e-9)).clamp(1.0, 2.5)
    });
    let vs0 = f0.as_ref().map_or(0.01, |f| f.stribeck_velocity);
    let s0 = f0
        .as_ref()
        .filter(|f| f.bristle_stiffness > 0.0)
        .map_or(0.3 * sc.stiffness, |f| f.bristle_stiffness);
    let z0 = f0
        .as_ref()
        .filter(|f| f.bristle_stiffness > 0.0)
        .map_or(0.2, |f| {
            f.bristle_damping / (2.0 * (f.bristle_stiffness * nominal.mechanics.mass).sqrt())
        });
    let seed = seeded(nominal, |e| {
        e.friction = Some(Friction {
            enabled: true,
            variant: FrictionVariant::Lugre,
            static_force: r0 * c0,
            coulomb_force: c0,
            stribeck_velocity: vs0,
            viscous: f0.as_ref().map_or(0.0, |f| f.viscous),
            bristle_stiffness: s0,
            bristle_damping: 0.0,
        })
    });
    let variant = |p: &mut PlantParams| {
        if let Some(f) = p.effects.friction.as_mut() {
            f.variant = FrictionVariant::Lugre;
        }
    };
    vec![
        // The Coulomb level moves the breakaway force with it (ratio set by the next).
        FreeParam::at_then(
            "effects.friction.coulomb_force",
            (1e-4 * sc.force, 0.1 * sc.force, true, c0),
            &seed,
            move |p| {
                variant(p);
                if let Some(f) = p.effects.friction.as_mut() {
                    f.static_force = f.coulomb_force;
                }
            },
        ),
        // A ratio, not a declared parameter: the value written is scaled to F_s = ratio·F_C.
        FreeParam::new(
            "effects.friction.static_force/coulomb_force",
            1.0,
            2.5,
            false,
            r0,
            write("effects.friction.static_force", &seed, move |p| {
                variant(p);
                if let Some(f) = p.effects.friction.as_mut() {
                    f.static_force *= f.coulomb_force;
                }
            }),
        ),
        FreeParam::at_then(
            "effects.friction.stribeck_velocity",
            (1e-3, 0.1, true, vs0),
            &seed,
            variant,
        ),
        FreeParam::at_then(
            "effects.friction.bristle_stiffness",
            (1e-3 * sc.stiffness, 10.0 * sc.stiffness, true, s0),
            &seed,
            variant,
        ),
        // A damping ratio, not a declared parameter: the value written is scaled to
        // σ₁ = ζ·2√(σ₀·m) with the (refit) moving mass.
        FreeParam::new(
            "effects.friction.bristle_damping/critical",
            0.01,
            2.0,
            true,
            z0.clamp(0.01, 2.0),
            write("effects.friction.bristle_damping", &seed, move |p| {
                variant(p);
                let m = p.mechanics.mass;
                if let Some(f) = p.effects.friction.as_mut() {
                    f.bristle_damping *= 2.0 * (f.bristle_stiffness * m).sqrt();
                }
            }),
        ),
    ]
}
