//! # ehactl-plant
//!
//! The nonlinear electro-hydraulic actuator plant of ehactl, in SI units. Every physical
//! effect is a separately switchable component named by its id in the effect catalogue of
//! `docs/design.md` ([`EffectId`]) and documented with the seed equation it implements:
//!
//! | module | physics | seed |
//! |---|---|---|
//! | [`valve`] | spool dynamics (PT1 / 2nd order), four metering edges, lap, saturation, K_C(P_d) | 003 eq. 9–13, 004 eq. 1, 20–23 |
//! | [`model`] | chambers over stroke, β(p), leakage, cavitation, mechanics, end stops, supply | 002 eq. 35, 003 eq. 1, 7–8, 14–15 |
//! | [`exact`] | exact discretisation of chambers + mechanics (`linear_exact`) | Van Loan 1978 |
//! | [`effects`] | the effect catalogue ([`EffectId`]), one module per effect: its config section and its own physics, e.g. [`effects::friction`] (static/Coulomb/Stribeck with true stick, LuGre), [`effects::supply_pressure_drop`] | the effect's seed, in its module docs |
//! | [`mod@line`] | lumped R-L-C lines | 002 eq. 9–17 |
//! | [`cbv`] | counterbalance valves: pilot-assisted relief + free-flow check | 002 eq. 18–19, fig. 2 |
//! | [`excitation`] | constant, harmonic, impact train | 003 eq. 2, 17 |
//! | [`sensors`] | load cell, pressures, position transducer, spool | 004, 003 |
//!
//! Each parameter is declared once, on its field in [`params`] (`#[param(unit, range, desc)]`);
//! the registry [`spec::params`] and the path accessor [`spec::ParamTree`] are generated from it.
#![deny(missing_docs)]

pub mod cbv;
mod chambers;
pub mod effects;
pub mod exact;
pub mod excitation;
pub mod imposed;
pub mod model;
pub mod params;
pub mod plausible;
mod registry;
pub mod rng;
pub mod sensors;
pub mod valve;

/// `friction`'s law with the stick state, under its historical path (now in
/// [`effects::friction`]).
pub use effects::friction;
/// `line_dynamics`' segment chains under their historical path (now in
/// [`effects::line_dynamics::line`]).
pub use effects::line_dynamics::line;

/// The parameter registry: the registry types (`Param`, `Range`, `ParamTree`,
/// `ConfigError`), which live in `ehactl-types` (crates/types/src/spec.rs) so that the
/// control laws and the backends declare parameters without compiling the plant (the checks
/// on a parsed TOML tree and the serde error mapping are `ehactl_config::tree`), and
/// the plant's own table ([`spec::params`]).
pub mod spec {
    pub use crate::registry::params;
    pub use ehactl_types::spec::*;
}

pub use effects::EffectId;
pub use model::{NumericalFailure, Plant, PlantState};
pub use params::PlantParams;
pub use sensors::Measurements;
pub use spec::ConfigError;
