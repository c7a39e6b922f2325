//! What of the parameter registry knows the plant: its table ([`params`]). Read through
//! [`crate::spec`], which adds the registry types of `ehactl-types`
//! (crates/types/src/spec.rs). Mapping a TOML parser's errors onto registry paths is the
//! config's (`ehactl_config::tree::from_serde`, crates/config/src/tree.rs): the plant
//! compiles no TOML parser.

use crate::params::PlantParams;
use ehactl_types::spec::{table, Param};
use std::sync::LazyLock;

/// The plant's parameters, generated once from the `#[param(...)]` declarations on the fields
/// of [`PlantParams`] (`#[derive(Params)]`, crate `ehactl-params-derive`), in declaration
/// order. Controller, setpoint, supervisor and run parameters are declared in `ehactl-config`.
pub fn params() -> &'static [Param] {
    static TABLE: LazyLock<Vec<Param>> = LazyLock::new(|| table::<PlantParams>(""));
    &TABLE
}
