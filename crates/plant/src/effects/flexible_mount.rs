//! `flexible_mount`: spring-damper (SDD) from the rod to a load mass (003 eq. 1), or a compliant
//! cylinder mount (variant `piston_side`; two-mass frame compliance, Jelali & Kroll 2003,
//! "Hydraulic Servo-systems", §4.4): the config section [`FlexibleMount`]
//! (`[effects.flexible_mount]`), the body's substep [`body_mount_step`] and the component
//! [`Mount`], the stage ([`MountStage`]) that couples the piston's velocity update to the load
//! mass or the cylinder body.

use super::component::{Component, LoadSpring, MountStage, PistonForces, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use serde::{Deserialize, Serialize};

/// Structural variant of `flexible_mount`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum MountVariant {
    /// Compliance on the load side: rod → spring-damper → load mass (003 eq. 1, SDD).
    #[default]
    LoadSide,
    /// Compliance on the piston side: the cylinder body (mass `load_mass`) sits on a
    /// spring-damper to ground and takes the reaction of the chamber pressures, seal friction
    /// and viscous force; the position transducer measures the piston relative to the body
    /// (chamber volumes follow it), the load spring acts on the absolute piston position
    /// (two-mass frame-compliance model, e.g. Jelali & Kroll 2003, "Hydraulic Servo-systems",
    /// §4.4 "mechanical structure").
    PistonSide,
}

/// `flexible_mount`: spring-damper (SDD) from rod to a load mass (003 eq. 1), or a compliant
/// cylinder mount (variant `piston_side`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FlexibleMount {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`load_side` or `piston_side`).
    #[serde(default)]
    #[param(
        choice,
        desc = "load_side: rod → spring-damper → load mass (003 SDD, default); piston_side: the \
         cylinder body (mass load_mass) on a spring-damper to ground"
    )]
    pub variant: MountVariant,
    /// Load mass m_L (kg); 003: 250. Variant `piston_side`: the cylinder body's mass.
    #[param(unit = "kg", range = Positive, desc = "load mass m_L (003: 250)")]
    pub load_mass: f64,
    /// SDD stiffness k_m (N/m); 003 range 1e4–1e5.
    #[param(unit = "N/m", range = Positive, desc = "SDD stiffness k_m")]
    pub stiffness: f64,
    /// SDD damping d_m (N·s/m); 003 range 1e4–2.5e4.
    #[param(unit = "N·s/m", range = NonNegative, desc = "SDD damping d_m")]
    pub damping: f64,
}

/// One substep of a compliant cylinder mount (`flexible_mount`, variant `piston_side`):
/// advances the body displacement `xb` (m) and velocity `vb` (m/s) with the reaction
/// `f_rel` (N) of the forces the oil and seals put on the piston (implicit in the mount's
/// damping), and returns the body's acceleration (m/s²) over the substep.
#[inline]
pub fn body_mount_step(
    xb: &mut f64,
    vb: &mut f64,
    f_rel: f64,
    (mb, km, dm): (f64, f64, f64),
    h: f64,
) -> f64 {
    let v_new = (mb * *vb + h * (-f_rel - km * *xb)) / (mb + h * dm);
    let a = (v_new - *vb) / h;
    *vb = v_new;
    *xb += h * v_new;
    a
}

/// The component of `flexible_mount`: what the piston's mechanics couple to (no mount, the
/// load mass on the rod's spring-damper, or the cylinder body on its mount). Its states, the
/// load mass's (or the body's) position x_L (m) and velocity v_L (m/s), are the plant state's
/// `x_load`, `v_load` (logged with it); the stage ([`MountStage`]) advances them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mount {
    /// No mount: the load moves with the rod (x_L = x, v_L = v).
    Rigid,
    /// Variant `load_side`: rod → spring-damper → load mass (003 eq. 1); the external force
    /// acts on the load mass.
    Load(MountCoefficients),
    /// Variant `piston_side`: the cylinder body on a spring-damper to ground; x, v are the
    /// piston's relative to the body, the load spring sees x + x_L.
    Body(MountCoefficients),
}

/// The spring-damper and the mass behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountCoefficients {
    /// Load mass m_L, or the body's (kg).
    pub mass: f64,
    /// Stiffness k_m (N/m).
    pub stiffness: f64,
    /// Damping d_m (N·s/m).
    pub damping: f64,
}

impl Component for Mount {
    type Section = FlexibleMount;

    /// The registry's per-field ranges are all (mass and stiffness > 0, damping ≥ 0).
    fn validate(_: &FlexibleMount) -> Result<(), ConfigError> {
        Ok(())
    }

    fn configure(s: Option<&FlexibleMount>, _setup: &Setup) -> Self {
        match s.filter(|m| m.enabled) {
            None => Mount::Rigid,
            Some(m) => {
                let k = MountCoefficients {
                    mass: m.load_mass,
                    stiffness: m.stiffness,
                    damping: m.damping,
                };
                match m.variant {
                    MountVariant::LoadSide => Mount::Load(k),
                    MountVariant::PistonSide => Mount::Body(k),
                }
            }
        }
    }

    /// No state of its own: x_L, v_L are set with the plant state.
    fn reset(&mut self) {}
}

impl MountStage for Mount {
    fn coefficients(&self) -> Option<(f64, f64, f64)> {
        match self {
            Mount::Rigid => None,
            Mount::Load(m) | Mount::Body(m) => Some((m.mass, m.stiffness, m.damping)),
        }
    }

    fn is_body(&self) -> bool {
        matches!(self, Mount::Body(_))
    }

    /// The load mass at the rod (x0), the body at rest in its mount (0).
    fn initial_load_position(&self, x0: f64) -> f64 {
        if self.is_body() {
            0.0
        } else {
            x0
        }
    }

    /// The load mass drifts with v_L; a rigid load follows the piston after its kick and
    /// the body moves with the force balance ([`MountStage::piston_force`]).
    #[inline]
    fn drift(&self, x_load: &mut f64, v_load: f64, h: f64) {
        if let Mount::Load(_) = self {
            *x_load += h * v_load;
        }
    }

    /// Rigid: F_hyd − K_L·(x − x_c) − F_ext. Load side: the spring-damper
    /// k_m·(x − x_L) − d_m·v_L on the piston (its d_m·v taken implicitly), the external force
    /// on the load mass (003 eq. 1). Body: the body takes the reaction of the oil, seal and
    /// viscous forces ([`body_mount_step`], advanced here), the load spring sees x + x_L and
    /// the piston the body's inertial force m·a_body; nothing implicit.
    #[inline]
    fn piston_force(
        &self,
        p: &PistonForces,
        x_load: &mut f64,
        v_load: &mut f64,
        h: f64,
    ) -> (f64, f64) {
        let k = p.spring;
        match *self {
            Mount::Rigid => (p.f_hyd - k.stiffness * (p.x - k.contact) - p.f_ext, 0.0),
            Mount::Load(m) => {
                let f_mount = m.stiffness * (p.x - *x_load) - m.damping * *v_load;
                (
                    p.f_hyd - k.stiffness * (p.x - k.contact) - f_mount,
                    m.damping,
                )
            }
            Mount::Body(m) => {
                let f_rel = p.f_hyd - p.damping * p.v - p.friction;
                let mb = (m.mass, m.stiffness, m.damping);
                let a_body = body_mount_step(x_load, v_load, f_rel, mb, h);
                (
                    p.f_hyd - k.stiffness * (p.x + *x_load - k.contact) - p.f_ext - p.mass * a_body,
                    0.0,
                )
            }
        }
    }

    /// Rigid: the load moves with the piston. Load side: the load mass's velocity, implicit
    /// in d_m: m_L·v̇_L = k_m·(x − x_L) + d_m·(v − v_L) − F_ext (003 eq. 1). Body: advanced
    /// with the force balance already.
    #[inline]
    fn follow(&self, x_load: &mut f64, v_load: &mut f64, x: f64, v: f64, f_ext: f64, h: f64) {
        match *self {
            Mount::Rigid => {
                *x_load = x;
                *v_load = v;
            }
            Mount::Load(m) => {
                let f = m.stiffness * (x - *x_load) + m.damping * v - f_ext;
                *v_load = (m.mass * *v_load + h * f) / (m.mass + h * m.damping);
            }
            Mount::Body(_) => {}
        }
    }

    /// Rigid: K_L·(x − x_c) + F_ext. Load side: K_L·(x − x_c) + k_m·(x − x_L) + d_m·(v − v_L).
    /// Body: K_L·(x + x_L − x_c) + F_ext.
    fn rod_force(
        &self,
        x: f64,
        v: f64,
        x_load: f64,
        v_load: f64,
        f_ext: f64,
        spring: LoadSpring,
    ) -> f64 {
        let k = spring;
        match *self {
            Mount::Rigid => k.stiffness * (x - k.contact) + f_ext,
            Mount::Load(m) => {
                k.stiffness * (x - k.contact)
                    + (m.stiffness * (x - x_load) + m.damping * (v - v_load))
            }
            Mount::Body(_) => k.stiffness * (x + x_load - k.contact) + f_ext,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(variant: MountVariant) -> FlexibleMount {
        FlexibleMount {
            enabled: true,
            variant,
            load_mass: 250.0,
            stiffness: 5e4,
            damping: 1.5e4,
        }
    }

    const SPRING: LoadSpring = LoadSpring {
        stiffness: 1e3,
        contact: 0.1,
    };

    fn forces(x: f64, v: f64) -> PistonForces {
        PistonForces {
            x,
            v,
            f_hyd: 2e3,
            f_ext: 500.0,
            friction: 40.0,
            spring: SPRING,
            mass: 20.0,
            damping: 300.0,
        }
    }

    /// Without the effect the load is rigid: it follows the piston, the external force and
    /// the load spring act on it, nothing is implicit.
    #[test]
    fn without_the_effect_the_load_follows_the_rod() {
        let setup = Setup {
            control_dt: 1e-3,
            supply_pressure: 20e6,
            bulk_modulus: 1.5e9,
            ..Setup::TEST
        };
        let mut off = section(MountVariant::LoadSide);
        off.enabled = false;
        for s in [None, Some(&off)] {
            let m = Mount::configure(s, &setup);
            assert_eq!(m, Mount::Rigid);
            assert_eq!((m.coefficients(), m.is_body()), (None, false));
            let (mut xl, mut vl) = (0.3, 0.0);
            m.drift(&mut xl, 1.0, 1e-3);
            assert_eq!(xl, 0.3);
            let (f, d) = m.piston_force(&forces(0.2, 0.1), &mut xl, &mut vl, 1e-3);
            assert_eq!((f, d), (2e3 - 1e3 * (0.2 - 0.1) - 500.0, 0.0));
            m.follow(&mut xl, &mut vl, 0.25, 0.05, 500.0, 1e-3);
            assert_eq!((xl, vl), (0.25, 0.05));
            let f = m.rod_force(0.2, 0.0, 0.0, 0.0, 500.0, SPRING);
            assert!((f - 600.0).abs() < 1e-9, "{f}");
        }
    }

    /// Load side (003 eq. 1): a load mass at rest on a stretched mount is pulled towards the
    /// rod by k_m·(x − x_L) less the external force, implicit in d_m; the piston feels the
    /// mount's spring and takes d_m implicitly.
    #[test]
    fn load_side_mass_follows_the_mount_force() {
        let m = Mount::configure(
            Some(&section(MountVariant::LoadSide)),
            &Setup {
                control_dt: 1e-3,
                supply_pressure: 20e6,
                bulk_modulus: 1.5e9,
                ..Setup::TEST
            },
        );
        assert_eq!(m.coefficients(), Some((250.0, 5e4, 1.5e4)));
        assert_eq!(m.initial_load_position(0.2), 0.2);
        let (mut xl, mut vl) = (0.19, 0.0);
        let (f, d) = m.piston_force(&forces(0.2, 0.0), &mut xl, &mut vl, 1e-4);
        assert_eq!(d, 1.5e4);
        assert!((f - (2e3 - 1e3 * 0.1 - 5e4 * 0.01)).abs() < 1e-9, "{f}");
        let h = 1e-4;
        m.follow(&mut xl, &mut vl, 0.2, 0.0, 200.0, h);
        let want = h * (5e4 * 0.01 - 200.0) / (250.0 + h * 1.5e4);
        assert!(
            vl > 0.0 && (vl - want).abs() < 1e-12 * want,
            "{vl} vs {want}"
        );
        m.drift(&mut xl, 1.0, h);
        assert!((xl - (0.19 + h)).abs() < 1e-15);
    }

    /// Piston side: the body starts at rest in its mount, moves with the reaction of the
    /// oil, seal and viscous forces, and the load spring sees the absolute piston position.
    #[test]
    fn piston_side_body_takes_the_reaction() {
        let m = Mount::configure(
            Some(&section(MountVariant::PistonSide)),
            &Setup {
                control_dt: 1e-3,
                supply_pressure: 20e6,
                bulk_modulus: 1.5e9,
                ..Setup::TEST
            },
        );
        assert!(m.is_body());
        assert_eq!(m.initial_load_position(0.2), 0.0);
        let (mut xb, mut vb) = (0.0, 0.0);
        let h = 1e-4;
        let p = forces(0.2, 0.1);
        let (f, d) = m.piston_force(&p, &mut xb, &mut vb, h);
        // Body velocity from the reaction −(F_hyd − d·v − F_f), implicit in d_m.
        let vb_want = h * -(2e3 - 300.0 * 0.1 - 40.0) / (250.0 + h * 1.5e4);
        assert!((vb - vb_want).abs() < 1e-15, "{vb}");
        assert!((xb - h * vb_want).abs() < 1e-18);
        let a = vb_want / h;
        let f_want = 2e3 - 1e3 * (0.2 + xb - 0.1) - 500.0 - 20.0 * a;
        assert!((f - f_want).abs() < 1e-9, "{f} vs {f_want}");
        assert_eq!(d, 0.0);
        // Nothing more after the kick; the rod force is the load spring's and F_ext.
        m.follow(&mut xb, &mut vb, 0.2, 0.1, 500.0, h);
        assert_eq!(vb, vb_want);
        let f = m.rod_force(0.2, 0.1, 0.01, 0.0, 500.0, SPRING);
        assert!((f - 610.0).abs() < 1e-9, "{f}");
    }
}
