//! # ehactl-types
//!
//! What the plant, the control laws, the logger and the backends share, with no I/O and no
//! physics:
//! - [`spec`], the parameter registry types that `#[derive(Params)]` (crate
//!   `ehactl-params-derive`) generates code against: [`spec::Param`], [`spec::ParamTree`],
//!   ranges, path access, TOML checks and [`spec::ConfigError`].
#![deny(missing_docs)]

pub mod spec;

pub use spec::ConfigError;
