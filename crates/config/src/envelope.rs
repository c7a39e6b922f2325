//! `[envelope]`: what a fitted law was fitted on, so that a prediction can say whether it
//! interpolates or extrapolates. `ehactl diagnose` writes it into the `extended.toml` of a
//! campaign; `ehactl predict` and `diagnose --validate` compare each record with it
//! (crates/ident/src/envelope.rs). A config without the section makes no such claim.
//!
//! ```toml
//! [[envelope.points]]          # one per fitted operating point
//! inputs = { current = 0.0 }   # the operating inputs (each in its declared unit)
//! records = 1                  # records fitted there
//! position = [0.0476, 0.0516]  # m: the range of the motion x
//! velocity = 0.052             # m/s: 99th percentile of |v|
//! acceleration = 3.9           # m/s²: 99th percentile of |a|
//! band = [0.45, 14.6]          # Hz: the band holding 90 % of the motion's power
//! resolution = 0.14            # Hz: the band's frequency resolution (1 / duration)
//! ```

use ehactl_plant::spec::ConfigError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The `[envelope]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Envelope {
    /// One entry per fitted operating point.
    #[serde(default)]
    pub points: Vec<EnvelopePoint>,
}

/// The motion a law was fitted on at one operating point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvelopePoint {
    /// Operating inputs (declared name → value in its unit).
    #[serde(default)]
    pub inputs: BTreeMap<String, f64>,
    /// Records fitted at this point (-).
    pub records: usize,
    /// Range [min, max] of the position x (m).
    pub position: [f64; 2],
    /// 99th percentile of |v| (m/s).
    pub velocity: f64,
    /// 99th percentile of |a| (m/s²).
    pub acceleration: f64,
    /// Band [low, high] holding the central 90 % of the motion's power (Hz).
    pub band: [f64; 2],
    /// Frequency resolution of `band` (Hz): 1 / the duration of the shortest fitted part.
    #[serde(default)]
    pub resolution: f64,
}

/// Check the section: finite numbers, ordered ranges, declared inputs.
pub fn validate(env: &Envelope, inputs: &crate::inputs::Inputs) -> Result<(), ConfigError> {
    for (k, p) in env.points.iter().enumerate() {
        let at = |what: &str| format!("envelope.points[{k}].{what}");
        for name in p.inputs.keys() {
            if !inputs.contains_key(name) {
                return Err(ConfigError::new(
                    at("inputs"),
                    format!("`{name}` is not a declared operating input ([inputs.{name}])"),
                ));
            }
        }
        let ordered = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] <= r[1];
        if !ordered(p.position) {
            return Err(ConfigError::new(
                at("position"),
                format!(
                    "{:?} is not a range [min, max] of finite positions (m)",
                    p.position
                ),
            ));
        }
        if !(ordered(p.band) && p.band[0] >= 0.0) {
            return Err(ConfigError::new(
                at("band"),
                format!(
                    "{:?} is not a band [low, high] of frequencies ≥ 0 (Hz)",
                    p.band
                ),
            ));
        }
        for (what, v, unit) in [
            ("velocity", p.velocity, "m/s"),
            ("acceleration", p.acceleration, "m/s²"),
            ("resolution", p.resolution, "Hz"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::new(
                    at(what),
                    format!("{v} is not a finite magnitude ≥ 0 ({unit})"),
                ));
            }
        }
        if p.inputs.values().any(|v| !v.is_finite()) {
            return Err(ConfigError::new(
                at("inputs"),
                "an input value is not finite",
            ));
        }
    }
    Ok(())
}
