//! # ehactl-analysis
//!
//! What a controls engineer checks before trusting a model: the configured rig and loop
//! linearised around their operating point (discrete-time, with the 5 kHz sample and hold,
//! and the continuous-time equivalent the papers use), loop margins and bandwidths, time-domain
//! frequency sweeps of the nonlinear plant, and the seed papers' closed forms.
//!
//! - [`oppoint`]: the operating point, found by running the noise-free loop to rest.
//! - [`linear`]: numerical linearisation of the plant's step map (x⁺ = A·x + B·u).
//! - [`loopshape`]: controller transfer functions, loop frequency response, margins.
//! - [`mod@analyze`]: the `ehactl analyze` result.
//! - [`mod@sweep`]: the `ehactl sweep` stepped-sine estimator on the nonlinear plant.
//! - [`sdd`]: Dindorf 2022's frequency and damping ratios of a spring-damper connection.
#![deny(missing_docs)]

pub mod analyze;
pub mod linear;
pub mod loopshape;
pub mod motion;
pub mod oppoint;
pub mod sdd;
pub mod sweep;
pub mod tline;

pub use analyze::{analyze, Analysis};
pub use sweep::{sweep, SweepOptions, SweepPoint, SweepResult};

/// Why an analysis could not be done.
#[derive(Debug)]
pub enum AnalysisError {
    /// The config is unusable.
    Config(ehactl_plant::ConfigError),
    /// The run or log failed.
    Session(ehactl_runtime::session::SessionError),
    /// The plant went non-finite while searching the operating point.
    Numerical(String),
}

impl std::fmt::Display for AnalysisError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AnalysisError::Config(e) => e.fmt(f),
            AnalysisError::Session(e) => e.fmt(f),
            AnalysisError::Numerical(s) => f.write_str(s),
        }
    }
}

impl std::error::Error for AnalysisError {}

impl From<ehactl_plant::ConfigError> for AnalysisError {
    fn from(e: ehactl_plant::ConfigError) -> Self {
        AnalysisError::Config(e)
    }
}
