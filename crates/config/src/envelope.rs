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

/// `[band]`: the spread of a fitted law, for the uncertainty band on its predictions
/// (crates/ident/src/band.rs). Written by a campaign beside `[envelope]`: `members` are the law
/// refitted on resamples of its fitting segments (a bootstrap), `relative_residual` the
/// out-of-sample error of the fit on its own data as a share of the force's spread.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Band {
    /// Two-sided level of the band (-), e.g. 0.9.
    pub level: f64,
    /// The fitted law's transfer NRMSE on its fitting records (-): the residual's standard
    /// deviation as a share of the predicted force's.
    pub relative_residual: f64,
    /// The law refitted on bootstrap resamples of its fitting segments.
    pub members: Vec<BandMember>,
}

/// One bootstrap refit of a `[effects.polynomial_force]` law and its input dependences.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandMember {
    /// The law at the config's operating point.
    pub polynomial_force: ehactl_plant::effects::PolynomialForce,
    /// Its dependences, per declared input (only `effects.polynomial_force.*` paths).
    #[serde(default)]
    pub inputs: BTreeMap<String, MemberDependence>,
}

/// A member's dependences on one input (see [`crate::inputs::OperatingInput`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct MemberDependence {
    /// Linear sensitivities by parameter path.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub linear: BTreeMap<String, f64>,
    /// Quadratic coefficients by parameter path.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub quadratic: BTreeMap<String, f64>,
    /// Saturating dependences by parameter path.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub saturating: BTreeMap<String, crate::inputs::Saturating>,
}

impl BandMember {
    /// `cfg` with this member's law and dependences in place of its own.
    pub fn apply(&self, cfg: &crate::RigConfig) -> crate::RigConfig {
        let mut out = cfg.clone();
        out.plant.effects.polynomial_force = Some(self.polynomial_force);
        let ours = |p: &String| p.starts_with("effects.polynomial_force.");
        for (name, inp) in out.inputs.iter_mut() {
            inp.linear.retain(|p, _| !ours(p));
            inp.quadratic.retain(|p, _| !ours(p));
            inp.saturating.retain(|p, _| !ours(p));
            if let Some(d) = self.inputs.get(name) {
                inp.linear.extend(d.linear.clone());
                inp.quadratic.extend(d.quadratic.clone());
                inp.saturating.extend(d.saturating.clone());
            }
        }
        out
    }

    /// The member of `cfg` as it stands (its law and dependences), `None` without a law.
    pub fn of(cfg: &crate::RigConfig) -> Option<BandMember> {
        let ours = |m: &BTreeMap<String, f64>| {
            m.iter()
                .filter(|(p, _)| p.starts_with("effects.polynomial_force."))
                .map(|(p, v)| (p.clone(), *v))
                .collect::<BTreeMap<_, _>>()
        };
        Some(BandMember {
            polynomial_force: cfg.plant.effects.polynomial_force?,
            inputs: cfg
                .inputs
                .iter()
                .map(|(n, i)| {
                    let d = MemberDependence {
                        linear: ours(&i.linear),
                        quadratic: ours(&i.quadratic),
                        saturating: i
                            .saturating
                            .iter()
                            .filter(|(p, _)| p.starts_with("effects.polynomial_force."))
                            .map(|(p, s)| (p.clone(), *s))
                            .collect(),
                    };
                    (n.clone(), d)
                })
                .collect(),
        })
    }
}

/// Check the `[band]` section: a level in (0, 1), a finite residual ≥ 0, members whose
/// dependences name declared inputs.
pub fn validate_band(band: &Band, inputs: &crate::inputs::Inputs) -> Result<(), ConfigError> {
    if !(band.level > 0.0 && band.level < 1.0) {
        return Err(ConfigError::new(
            "band.level",
            format!(
                "{} is not a two-sided level in (0, 1), e.g. 0.9",
                band.level
            ),
        ));
    }
    if !(band.relative_residual.is_finite() && band.relative_residual >= 0.0) {
        return Err(ConfigError::new(
            "band.relative_residual",
            format!("{} is not a finite share ≥ 0", band.relative_residual),
        ));
    }
    for (k, m) in band.members.iter().enumerate() {
        if let Some(name) = m.inputs.keys().find(|n| !inputs.contains_key(*n)) {
            return Err(ConfigError::new(
                format!("band.members[{k}].inputs"),
                format!("`{name}` is not a declared operating input ([inputs.{name}])"),
            ));
        }
    }
    Ok(())
}
