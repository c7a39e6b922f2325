//! `flexible_mount`: spring-damper from the rod to a load mass, or a compliant cylinder mount
//! (variant `piston_side`, same parameters). Model and sources: `FlexibleMount` in
//! crates/plant/src/effects/flexible_mount.rs.
//!
//! Seeds: load mass = moving mass (0.02…20×), stiffness k = m·ω² at the residual's mode frequency
//! (10⁻³…10× the hydraulic stiffness), damping ratio 0.1 of the critical 2·√(k·m).

use super::{EffectFit, Signature};
use crate::evidence::Analysis;
use crate::freeparam::{seeded, write, FreeParam, Scales};
use ehactl_plant::params::{FlexibleMount, MountVariant};
use ehactl_plant::{EffectId, PlantParams};
use std::sync::Arc;

/// The catalogue effect `flexible_mount`.
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
            EffectId::BulkModulusPressure | EffectId::LineDynamics => Some(super::MODE_EXPERIMENT),
            _ => None,
        }
    }

    fn prior(&self, an: &Analysis, _dt: f64) -> (f64, String) {
        an.mode_prior()
    }

    fn params(&self, nominal: &PlantParams, sc: &Scales, an: &Analysis) -> Option<Vec<FreeParam>> {
        let ef = &nominal.effects;
        let at = FreeParam::at;
        let cur = ef.flexible_mount.clone();
        let m0 = cur.as_ref().map_or(sc.mass, |m| m.load_mass);
        let w = std::f64::consts::TAU * an.mode_frequency.max(1.0);
        let k0 = cur.as_ref().map_or(
            (m0 * w * w).clamp(1e-3 * sc.stiffness, 10.0 * sc.stiffness),
            |m| m.stiffness,
        );
        let z0 = cur.as_ref().map_or(0.1, |m| {
            m.damping / (2.0 * (m.stiffness * m.load_mass).sqrt())
        });
        let base = cur.unwrap_or(FlexibleMount {
            enabled: true,
            variant: MountVariant::LoadSide,
            load_mass: m0,
            stiffness: k0,
            damping: 0.0,
        });
        let seed = seeded(nominal, |e| e.flexible_mount = Some(base));
        Some(vec![
            at(
                "effects.flexible_mount.load_mass",
                (0.02 * sc.mass, 20.0 * sc.mass, true, m0),
                &seed,
            ),
            at(
                "effects.flexible_mount.stiffness",
                (1e-3 * sc.stiffness, 10.0 * sc.stiffness, true, k0),
                &seed,
            ),
            // A damping ratio, not a declared parameter: the value written is scaled to
            // d_m = ζ·2√(k_m·m_L).
            FreeParam::new(
                "effects.flexible_mount.damping/critical",
                0.005,
                2.0,
                true,
                z0,
                write("effects.flexible_mount.damping", &seed, |p| {
                    if let Some(m) = p.effects.flexible_mount.as_mut() {
                        m.damping = m.damping * 2.0 * (m.stiffness * m.load_mass).sqrt();
                    }
                }),
            ),
        ])
    }

    fn variants(
        &self,
        nominal: &PlantParams,
        _sc: &Scales,
        first: Vec<FreeParam>,
    ) -> Vec<(&'static str, Vec<FreeParam>)> {
        let ef = &nominal.effects;
        let mut out = Vec::new();
        let cur = ef.flexible_mount.as_ref().map(|d| d.variant);
        if cur.is_none() {
            // Same parameters, the other structure: the body of the cylinder on the mount.
            let body: Vec<FreeParam> = first
                .iter()
                .map(|fp| {
                    let set = fp.set.clone();
                    let mut q = fp.clone();
                    q.set = Arc::new(move |p, v| {
                        set(p, v);
                        if let Some(m) = p.effects.flexible_mount.as_mut() {
                            m.variant = MountVariant::PistonSide;
                        }
                    });
                    q
                })
                .collect();
            out.push(("load_side", first));
            out.push(("piston_side", body));
        } else {
            let v = if cur == Some(MountVariant::PistonSide) {
                "piston_side"
            } else {
                "load_side"
            };
            out.push((v, first));
        }
        out
    }
}
