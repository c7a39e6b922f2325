//! Operating inputs: signals a record may carry that are not loop signals but set the rig's
//! operating point — an MR damper's coil current (A), a supply pressure, an oil temperature —
//! and that plant parameters may depend on.
//!
//! ```toml
//! [inputs.current]
//! unit = "A"             # the input's SI unit
//! value = 0.0            # operating point the plant section describes (and `ehactl run` uses)
//! [inputs.current.linear]       # ∂p/∂current of each dependent parameter (its unit per A)
//! "effects.polynomial_force.dahl" = 1027.0
//! [inputs.current.quadratic]    # ½·∂²p/∂current² (its unit per A²), optional
//! [inputs.current.saturating."effects.polynomial_force.coulomb"]  # optional
//! gain = 850.0           # g (the parameter's unit): the rise from i = 0 to saturation
//! scale = 0.25           # i_s (A): the input at which 63 % of the rise is reached
//! [inputs.current.hinge."effects.polynomial_force.viscous"]  # optional
//! knot = 0.5             # i_k (A): the knee of a piecewise-linear dependence
//! slope = -4000.0        # s (the parameter's unit per A): the change of slope beyond i_k
//! ```
//!
//! A parameter p with dependences is
//! p(i) = p₀ + a·(i − i₀) + b·(i − i₀)² + g·(e^(−i₀/i_s) − e^(−i/i_s)) +
//! s·(max(i − i_k, 0) − max(i₀ − i_k, 0)) where p₀ is the
//! value the plant section states and i₀ the input's `value` (the saturating part is the
//! magnetic saturation of an MR damper's coil, g·(1 − e^(−i/i_s)): Spencer, Dyke, Sain &
//! Carlson 1997, J. Eng. Mech. 123(3):230–238 take the damper's coefficients affine in the
//! coil's filtered voltage; the exponential rise is the saturating form a campaign fits,
//! crates/ident/src/campaign/): the plant section stays the
//! model at its own operating point (so `ehactl run` needs nothing else), and a record logged
//! at another operating point is replayed with [`plant_at`]. A record column named like
//! a declared input carries it (`ehactl diagnose`, `ehactl predict`); an undeclared column is an
//! error there.

use ehactl_plant::spec::{ConfigError, ParamTree};
use ehactl_plant::PlantParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One declared operating input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OperatingInput {
    /// SI unit of the input (e.g. `A`), as a record's column carries it.
    pub unit: String,
    /// Operating point (in `unit`) at which the plant section holds (default 0).
    #[serde(default)]
    pub value: f64,
    /// Linear sensitivities ∂p/∂input by parameter path (the parameter's unit per `unit`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub linear: BTreeMap<String, f64>,
    /// Quadratic coefficients ½·∂²p/∂input² by parameter path (its unit per `unit`²).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub quadratic: BTreeMap<String, f64>,
    /// Saturating dependences g·(1 − e^(−i/i_s)) by parameter path.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub saturating: BTreeMap<String, Saturating>,
    /// Knees s·max(i − i_k, 0) of piecewise-linear dependences by parameter path.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub hinge: BTreeMap<String, Hinge>,
}

/// A knee of a piecewise-linear dependence of a parameter on an input: s·max(i − i_k, 0),
/// added to the linear term, so that the slope is a below i_k and a + s above it (a
/// campaign's piecewise form between its fitted operating points).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hinge {
    /// i_k: the input at the knee (the input's unit).
    pub knot: f64,
    /// s: the change of slope beyond the knee (the parameter's unit per the input's unit).
    pub slope: f64,
}

impl Hinge {
    /// s·max(i − i_k, 0) at input `i`.
    pub fn at(&self, i: f64) -> f64 {
        self.slope * (i - self.knot).max(0.0)
    }
}

/// A saturating dependence of a parameter on an input: g·(1 − e^(−i/i_s)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Saturating {
    /// g: the rise from i = 0 to saturation (the parameter's unit).
    pub gain: f64,
    /// i_s: the input at which 1 − 1/e of the rise is reached (the input's unit, > 0).
    pub scale: f64,
}

impl Saturating {
    /// g·(1 − e^(−i/i_s)) at input `i`.
    pub fn at(&self, i: f64) -> f64 {
        self.gain * (1.0 - (-i / self.scale).exp())
    }
}

/// The `[inputs]` section: declared operating inputs by name (a record's column name).
pub type Inputs = BTreeMap<String, OperatingInput>;

/// Column names a record uses for loop signals and outputs: no input may take one.
pub const RESERVED_COLUMNS: [&str; 9] = ["t", "u", "force", "x", "p_a", "p_b", "x_v", "ref", "v"];

/// Check the section against the plant: names are column-like and not reserved, units
/// given, values finite, every dependent path a float parameter present in `plant`.
pub fn validate(inputs: &Inputs, plant: &PlantParams) -> Result<(), ConfigError> {
    for (name, inp) in inputs {
        let at = |what: &str| format!("inputs.{name}{what}");
        let ok_name = name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_lowercase() || c == '_')
            && name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !ok_name || RESERVED_COLUMNS.contains(&name.as_str()) {
            return Err(ConfigError::new(
                at(""),
                format!(
                    "`{name}` cannot name an operating input; expected a lower-case column name (letters, digits, `_`) other than {}",
                    RESERVED_COLUMNS.join(", ")
                ),
            ));
        }
        if inp.unit.trim().is_empty() {
            return Err(ConfigError::new(
                at(".unit"),
                "empty unit; expected the input's SI unit, e.g. \"A\"",
            ));
        }
        if !inp.value.is_finite() {
            return Err(ConfigError::new(
                at(".value"),
                format!(
                    "{} is not finite; expected the operating point in {}",
                    inp.value, inp.unit
                ),
            ));
        }
        for (kind, table) in [("linear", &inp.linear), ("quadratic", &inp.quadratic)] {
            for (path, c) in table {
                let Some(_) = plant.get_path(path) else {
                    return Err(ConfigError::new(
                        at(&format!(".{kind}.\"{path}\"")),
                        format!("`{path}` is not a float parameter present in this config's plant; expected the dotted path of one (see `ehactl params`)"),
                    ));
                };
                if !c.is_finite() {
                    return Err(ConfigError::new(
                        at(&format!(".{kind}.\"{path}\"")),
                        format!("{c} is not finite"),
                    ));
                }
            }
        }
        for (path, s) in &inp.saturating {
            let here = at(&format!(".saturating.\"{path}\""));
            if plant.get_path(path).is_none() {
                return Err(ConfigError::new(
                    here,
                    format!("`{path}` is not a float parameter present in this config's plant; expected the dotted path of one (see `ehactl params`)"),
                ));
            }
            if !s.gain.is_finite() {
                return Err(ConfigError::new(
                    here,
                    format!("gain {} is not finite", s.gain),
                ));
            }
            if !(s.scale.is_finite() && s.scale > 0.0) {
                return Err(ConfigError::new(
                    here,
                    format!(
                        "scale {} is not a positive finite number; expected the input ({}) at which 63 % of the rise is reached",
                        s.scale, inp.unit
                    ),
                ));
            }
        }
        for (path, h) in &inp.hinge {
            let here = at(&format!(".hinge.\"{path}\""));
            if plant.get_path(path).is_none() {
                return Err(ConfigError::new(
                    here,
                    format!("`{path}` is not a float parameter present in this config's plant; expected the dotted path of one (see `ehactl params`)"),
                ));
            }
            if !(h.knot.is_finite() && h.slope.is_finite()) {
                return Err(ConfigError::new(
                    here,
                    format!(
                        "knot {} ({}) and slope {} must be finite; expected the knee's input and the change of slope beyond it",
                        h.knot, inp.unit, h.slope
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// An operating point in words: `current = 0.5, temperature = 40` (empty when none).
pub fn describe_point(at: &BTreeMap<String, f64>) -> String {
    at.iter()
        .map(|(k, v)| format!("{k} = {v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The registry's range check ([`ehactl_plant::spec::params`], the one `check-config` runs on
/// the file) on the value `v` a dependence gives the parameter `path` at an operating point:
/// `Err` holds the rest of the message (unit, out of range, what was expected).
fn check_range(path: &str, v: f64) -> Result<(), String> {
    let tables = [ehactl_plant::spec::params()];
    match ehactl_plant::spec::find(&tables, path) {
        Some(p) if !p.range.admits(v) => Err(format!(
            " {}, out of range; {} (check-config checks the file's value, the dependence leaves it here; narrow the operating range or the dependence)",
            p.unit,
            ehactl_plant::spec::expectation(&tables, path)
        )),
        _ => Ok(()),
    }
}

/// The plant at operating point `at` (input name → value in its unit); an input not given
/// stays at its declared `value`. Errors name an unknown input or a parameter the dependence
/// drives out of its admitted range.
pub fn plant_at(
    inputs: &Inputs,
    plant: &PlantParams,
    at: &BTreeMap<String, f64>,
) -> Result<PlantParams, String> {
    for name in at.keys() {
        if !inputs.contains_key(name) {
            return Err(format!(
                "operating input `{name}` is not declared; the config declares [{}]",
                inputs.keys().cloned().collect::<Vec<_>>().join(", ")
            ));
        }
    }
    let mut p = plant.clone();
    for (name, inp) in inputs {
        let d = at.get(name).map_or(0.0, |v| v - inp.value);
        if d == 0.0 {
            continue;
        }
        let paths: std::collections::BTreeSet<&String> = inp
            .linear
            .keys()
            .chain(inp.quadratic.keys())
            .chain(inp.saturating.keys())
            .chain(inp.hinge.keys())
            .collect();
        for path in paths {
            let Some(v) = p.get_path(path) else {
                return Err(format!("inputs.{name}: `{path}` is not in the plant"));
            };
            let a = inp.linear.get(path).copied().unwrap_or(0.0);
            let b = inp.quadratic.get(path).copied().unwrap_or(0.0);
            let i = at.get(name).copied().unwrap_or(inp.value);
            let sat = inp
                .saturating
                .get(path)
                .map_or(0.0, |s| s.at(i) - s.at(inp.value));
            let knee = inp
                .hinge
                .get(path)
                .map_or(0.0, |h| h.at(i) - h.at(inp.value));
            let new = v + a * d + b * d * d + sat + knee;
            p.set_path(path, new).map_err(|e| {
                format!(
                    "inputs.{name} = {} {}: `{path}` becomes {new}: {e}",
                    at[name], inp.unit
                )
            })?;
            check_range(path, new).map_err(|e| {
                format!(
                    "inputs.{name} = {} {}: `{path}` becomes {new}{e}",
                    at[name], inp.unit
                )
            })?;
        }
    }
    ehactl_plant::model::validate(&p)
        .map_err(|e| format!("the plant at operating point {}: {e}", describe_point(at)))?;
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MTS rig with its MR damper (`[inputs.current]`, value 0 A, mass 10 kg).
    fn mts(extra: &str) -> crate::RigConfig {
        let text = include_str!("../../../configs/utfsm_mts_mrdamper.toml");
        crate::RigConfig::from_toml_str(&format!("{text}\n{extra}")).unwrap()
    }

    fn at(i: f64) -> BTreeMap<String, f64> {
        BTreeMap::from([("current".to_string(), i)])
    }

    #[test]
    fn a_dependence_may_not_push_a_parameter_out_of_its_range() {
        // 10 kg − 100 kg/A · 1 A = −90 kg: a mass must be > 0 (registry range `Positive`).
        let cfg = mts("[inputs.current.linear]\n\"mechanics.mass\" = -100.0\n");
        let ok = plant_at(&cfg.inputs, &cfg.plant, &at(0.05)).unwrap();
        assert!((ok.mechanics.mass - 5.0).abs() < 1e-12);
        let e = plant_at(&cfg.inputs, &cfg.plant, &at(1.0)).unwrap_err();
        assert!(
            e.contains("inputs.current = 1 A")
                && e.contains("`mechanics.mass` becomes -90 kg")
                && e.contains("out of range")
                && e.contains("> 0"),
            "{e}"
        );
    }

    #[test]
    fn a_negative_pre_yield_travel_is_refused() {
        let cfg = mts("[inputs.current.linear]\n\"effects.polynomial_force.dahl_travel\" = -1.0\n");
        let e = plant_at(&cfg.inputs, &cfg.plant, &at(2.0)).unwrap_err();
        assert!(
            e.contains("effects.polynomial_force.dahl_travel") && e.contains("out of range"),
            "{e}"
        );
    }
}
