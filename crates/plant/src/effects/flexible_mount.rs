//! `flexible_mount`: spring-damper (SDD) from the rod to a load mass (003 eq. 1), or a compliant
//! cylinder mount (variant `piston_side`; two-mass frame compliance, Jelali & Kroll 2003,
//! "Hydraulic Servo-systems", §4.4): the config section [`FlexibleMount`]
//! (`[effects.flexible_mount]`) and the body's substep [`body_mount_step`].

use super::switch::yes;
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

/// What `Plant::configure` (crates/plant/src/model.rs) derives from the section `s` (used when
/// present and enabled): the mount (load mass, or the body's for `piston_side` (kg),
/// stiffness (N/m), damping (N·s/m)) and whether it is the cylinder body's (variant
/// `piston_side`).
pub(crate) fn configure(s: Option<&FlexibleMount>) -> (Option<(f64, f64, f64)>, bool) {
    let mount = s.filter(|m| m.enabled);
    (
        mount.map(|m| (m.load_mass, m.stiffness, m.damping)),
        mount.is_some_and(|m| m.variant == MountVariant::PistonSide),
    )
}
