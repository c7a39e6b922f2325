//! Small-magnitude cases scored against the diagnosis' stated detection limits
//! (`ehactl_ident::limits`; DIAGNOSIS.md "Small magnitudes scored against the detection
//! limits").
//!
//! A small case is the clean record plus α × (the record with the effect − the clean record)
//! ([`crate::synth::small_effect`]): to first order the effect at α × its strength. Its hidden
//! size is stated in the limit's own parameter and unit: α × the drawn value for a parameter
//! whose larger value is the stronger effect (a force, a width, a coefficient, a delay, a
//! length, a slope, an amplitude); the drawn value / α for a stiffness or a natural frequency
//! (a compliance, a lag α-scaled); 1 − α·(1 − L) for a spool limit L (the clipped share of the
//! stroke α-scaled). The ratio hidden / limit is taken on the strength scale (the value, or
//! its inverse when a smaller value is stronger). These maps are first order and, for the independent generator's
//! structures, the nearest catalogue parameter: a first-order spool of time constant τ is the
//! natural frequency 1/τ, a two-effect, a hose, entrained air and a pump limit have none
//! (their cases are scored `n/a`).

use crate::indep::Hidden;
use ehactl_ident::limits::DetectionLimit;
use ehactl_ident::Diagnosis;
use ehactl_plant::spec::ParamTree;
use ehactl_plant::PlantParams;

/// The strength of value `v` of `parameter` (larger = stronger): the value itself, its
/// inverse when a smaller value is the stronger effect. (A spool limit too: 1 − L is no
/// scale for it, as a limit at the full stroke L = 1 can be detected on a record whose
/// command reaches beyond full scale.)
fn strength(stronger: &str, v: f64) -> f64 {
    if stronger == "larger" {
        v
    } else {
        1.0 / v
    }
}

/// The value of `parameter` at α × the strength of value `v` (see the module doc).
fn scaled(parameter: &str, stronger: &str, v: f64, alpha: f64) -> f64 {
    if stronger == "larger" {
        alpha * v
    } else if parameter.ends_with("spool_limit") {
        1.0 - alpha * (1.0 - v)
    } else {
        v / alpha
    }
}

/// Hidden strength over the stated limit's (-) for a hidden value `size` of the limit's
/// parameter: above 1 the stated limit says the record should have shown it. A limit of
/// "not detectable with this record" is infinite (ratio 0); `None` when no limit is stated
/// (the effect in the nominal config, not testable).
pub fn ratio(limit: &DetectionLimit, size: f64) -> Option<f64> {
    let s = strength(&limit.stronger, size);
    match limit.limit {
        Some(l) => Some(s / strength(&limit.stronger, l)),
        None if limit.note == "not detectable with this record" => Some(0.0),
        None => None,
    }
}

/// The full-size value of the independent generator's hidden effect `h` in the catalogue
/// parameter `parameter` (dotted path as in [`DetectionLimit::parameter`]); `None` when the
/// generator's structure has no counterpart in it.
pub fn indep_value(h: &Hidden, parameter: &str) -> Option<f64> {
    let last = parameter.rsplit('.').next().unwrap_or(parameter);
    let v = match (h, last) {
        (Hidden::LuGre { fc, .. }, "coulomb_force")
        | (Hidden::LoadCoulomb { fc, .. }, "coulomb_force")
        | (Hidden::Dahl { fc, .. }, "coulomb_force") => *fc,
        (Hidden::Overlap { ov, .. }, "overlap" | "deadzone") => *ov,
        (Hidden::AmpDeadzone { d, .. }, "overlap" | "deadzone") => *d,
        (Hidden::SoftSaturation { l }, "spool_limit") => *l,
        (Hidden::AsymSaturation { lp, ln }, "spool_limit") => lp.min(*ln),
        (Hidden::Spool1 { tau }, "natural_frequency") => 1.0 / tau,
        (Hidden::Spool1 { tau }, "time_constant") => *tau,
        (Hidden::Spool2 { wn, .. }, "natural_frequency") => *wn,
        (Hidden::Spool2 { wn, .. }, "time_constant") => 1.0 / wn,
        (Hidden::InternalLeak { k }, "coefficient")
        | (Hidden::ExternalLeakBoth { k }, "coefficient")
        | (Hidden::ExternalLeakA { k }, "coefficient") => *k,
        (Hidden::LinearBeta { slope, .. }, "slope") => *slope,
        (Hidden::Lines { len, .. }, "length") => *len,
        (Hidden::LoadMount { k, .. }, "stiffness") | (Hidden::BodyMount { k, .. }, "stiffness") => {
            *k
        }
        (Hidden::Delay { tau }, "delay") => *tau,
        (Hidden::Tone { a, .. }, _) if last.starts_with("sine_amplitudes") => *a,
        (Hidden::SupplyResistance { r, .. }, "resistance") => *r,
        _ => return None,
    };
    Some(v)
}

/// The full-size value of `parameter` in the own plant's truth `truth`; a spool's natural
/// frequency from its time constant (1/τ) and the reverse when only the other is set.
pub fn synth_value(truth: &PlantParams, parameter: &str) -> Option<f64> {
    let get = |p: &str| truth.get_path(p).filter(|v| v.is_finite() && *v > 0.0);
    get(parameter).or_else(|| {
        let other = match parameter.rsplit('.').next()? {
            "natural_frequency" => "effects.valve_dynamics.time_constant",
            "time_constant" => "effects.valve_dynamics.natural_frequency",
            "overlap" => return get("effects.valve_deadband.deadzone"),
            "deadzone" => return get("effects.valve_deadband.overlap"),
            _ => return None,
        };
        get(other).map(|v| 1.0 / v)
    })
}

/// The hidden size of a small case in `limit`'s parameter: its full-size value `full` at α.
pub fn small_size(limit: &DetectionLimit, full: f64, alpha: f64) -> f64 {
    scaled(&limit.parameter, &limit.stronger, full, alpha)
}

/// Whether diagnosis `d` names effect `want`: among its causes, or in an ambiguity (the
/// effect id in backquotes).
pub fn names(d: &Diagnosis, want: &str) -> bool {
    let quoted = format!("`{want}`");
    d.causes.iter().any(|c| c == want) || d.ambiguities.iter().any(|a| a.contains(&quoted))
}

/// Whether diagnosis `d` gives `want` as the closest catalogue effect of a record it does not
/// explain (`Diagnosis::closest`).
pub fn closest_is(d: &Diagnosis, want: &str) -> bool {
    d.closest.as_ref().is_some_and(|c| c.effect == want)
}

/// α of a small case from its record's source text (`… α = 1.234e-1)`), as
/// [`crate::indep::make_case_small`] writes it.
pub fn alpha_from_source(source: &str) -> Option<f64> {
    let rest = source.split("α = ").nth(1)?;
    rest.trim_end_matches(')').trim().parse().ok()
}

/// The scores of a list of small cases against their stated limits.
#[derive(Debug, Default, Clone)]
pub struct LimitScore {
    /// Cases whose hidden size could be stated in the limit's parameter.
    pub scored: usize,
    /// Cases answered `none` with the hidden effect above its stated limit (ratio > 1).
    pub false_none_above: Vec<String>,
    /// Cases at ≥ 1.5× their limit: (run, named).
    pub at_1_5: (usize, usize),
    /// Of those not named, the ones whose closest catalogue effect is the hidden one.
    pub closest_at_1_5: usize,
    /// The cases at ≥ 1.5× not named: one line each.
    pub missed_at_1_5: Vec<String>,
    /// Cases without a size map or a stated limit.
    pub not_scored: Vec<String>,
}

impl LimitScore {
    /// Add one case: its label, the answer, the ratio hidden / limit (`None`: not scored),
    /// whether the answer names the hidden effect, whether its closest effect is it.
    pub fn add(
        &mut self,
        label: &str,
        answer: &str,
        ratio: Option<f64>,
        named: bool,
        closest: bool,
    ) {
        let Some(r) = ratio else {
            self.not_scored.push(label.to_string());
            return;
        };
        self.scored += 1;
        if answer == "none" && r > 1.0 {
            self.false_none_above
                .push(format!("{label} ({r:.2}× its limit)"));
        }
        if r >= 1.5 {
            self.at_1_5.0 += 1;
            self.at_1_5.1 += named as usize;
            if !named {
                self.closest_at_1_5 += closest as usize;
                self.missed_at_1_5.push(format!(
                    "{label} ({r:.2}×, answered {answer}{})",
                    if closest { ", the closest effect" } else { "" }
                ));
            }
        }
    }

    /// A markdown table of the scores.
    pub fn table(&self) -> String {
        let list = |v: &[String]| {
            if v.is_empty() {
                "—".to_string()
            } else {
                v.join("; ")
            }
        };
        format!(
            "\nSmall cases scored against the stated detection limits (ratio = hidden size / stated limit, `ehactl_ident_eval::limscore`):\n\n| measure | result | target |\n|---|---|---|\n| cases scored (size map and limit) | {} | — |\n| false `none` above the stated limit | {} ({}) | 0 |\n| named at ≥ 1.5× the limit (cause or ambiguity) | {}/{} | ≥ 90 % |\n| of the others, the closest effect of an unexplained record | {} | — |\n| not named at ≥ 1.5× | {} | — |\n| not scored | {} | — |\n",
            self.scored,
            self.false_none_above.len(),
            list(&self.false_none_above),
            self.at_1_5.1,
            self.at_1_5.0,
            self.closest_at_1_5,
            list(&self.missed_at_1_5),
            list(&self.not_scored),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limit(parameter: &str, stronger: &str, v: f64) -> DetectionLimit {
        DetectionLimit {
            parameter: parameter.into(),
            unit: "-".into(),
            stronger: stronger.into(),
            limit: Some(v),
            range: [0.0, 1.0],
            note: String::new(),
            looseness: 0.5,
            variant: "-".into(),
            shape: String::new(),
            method: "linearised".into(),
        }
    }

    /// The sizing parameters a limit can be stated in, with the side that is stronger.
    const SIZES: [(&str, &str); 10] = [
        ("effects.friction.coulomb_force", "larger"),
        ("effects.valve_deadband.overlap", "larger"),
        ("effects.valve_saturation.spool_limit", "smaller"),
        ("effects.valve_dynamics.natural_frequency", "smaller"),
        ("effects.internal_leakage.coefficient", "larger"),
        ("effects.bulk_modulus_pressure.slope", "larger"),
        ("effects.line_dynamics.length", "larger"),
        ("effects.flexible_mount.stiffness", "smaller"),
        ("effects.time_delay.delay", "larger"),
        ("effects.supply_pressure_drop.resistance", "larger"),
    ];

    /// A physical small case (`indep::Hidden::at_strength`) holds the size the blend's
    /// scoring states for it: on every generator variant and every sizing parameter it has,
    /// the value at α is [`small_size`] of the full value. So a limit checked on physical
    /// cases is scored on the size actually simulated.
    #[test]
    fn the_independent_generators_physical_size_is_the_scored_size() {
        let rig = crate::indep::Rig::default();
        let alpha = 0.137;
        let mut checked = 0;
        for kind in crate::indep::KINDS {
            let mut g = crate::indep::Pcg::new(7);
            let Some(h) = crate::indep::draw(kind, &rig, &mut g) else {
                continue;
            };
            assert_eq!(h.at_strength(1.0), h, "{kind}");
            for (p, stronger) in SIZES {
                let (Some(full), Some(small)) =
                    (indep_value(&h, p), indep_value(&h.at_strength(alpha), p))
                else {
                    continue;
                };
                let want = small_size(&limit(p, stronger, 1.0), full, alpha);
                assert!(
                    (small - want).abs() <= 1e-12 * want.abs(),
                    "{kind} {p}: {small} vs {want}"
                );
                checked += 1;
            }
        }
        assert!(
            checked >= 18,
            "only {checked} variants have a sizing parameter"
        );
    }

    /// The same for the own plant's hidden effects (`hide::at_strength`) against
    /// [`synth_value`].
    #[test]
    fn the_own_plants_physical_size_is_the_scored_size() {
        let alpha = 0.137;
        let mut checked = 0;
        for e in ehactl_plant::EffectId::ALL {
            let mut full = crate::synth::testrig().plant;
            crate::hide::hide(e, &mut full, &mut crate::rng::Rng::new(11));
            let mut small = full.clone();
            crate::hide::at_strength(e, &mut small, alpha);
            for (p, stronger) in SIZES {
                let (Some(f), Some(v)) = (synth_value(&full, p), synth_value(&small, p)) else {
                    continue;
                };
                let want = small_size(&limit(p, stronger, 1.0), f, alpha);
                assert!(
                    (v - want).abs() <= 1e-9 * want.abs(),
                    "{e:?} {p}: {v} vs {want}"
                );
                checked += 1;
            }
        }
        assert!(
            checked >= 9,
            "only {checked} effects have a sizing parameter"
        );
    }

    /// Ratios on the three strength scales, by hand: a delay 2× its limit; a mount half as
    /// stiff as its limit (2× the compliance); a spool limit of 0.7 against a limit of 0.85
    /// (on the inverse scale: 0.85 / 0.7).
    #[test]
    fn ratios_on_the_strength_scale() {
        let d = limit("effects.time_delay.delay", "larger", 1e-3);
        assert!((ratio(&d, 2e-3).unwrap() - 2.0).abs() < 1e-12);
        let m = limit("effects.flexible_mount.stiffness", "smaller", 1e7);
        assert!((ratio(&m, 5e6).unwrap() - 2.0).abs() < 1e-12);
        let s = limit("effects.valve_saturation.spool_limit", "smaller", 0.85);
        assert!((ratio(&s, 0.7).unwrap() - 0.85 / 0.7).abs() < 1e-9);
        // α-scaling: a limit of 0.5 at α = 0.1 clips 5 % of the stroke.
        assert!((small_size(&s, 0.5, 0.1) - 0.95).abs() < 1e-12);
        assert!((small_size(&m, 1e7, 0.1) - 1e8).abs() < 1e-3);
        let mut u = d.clone();
        u.limit = None;
        u.note = "not detectable with this record".into();
        assert_eq!(ratio(&u, 1.0), Some(0.0));
        u.note = "in the nominal config already".into();
        assert_eq!(ratio(&u, 1.0), None);
    }

    #[test]
    fn alpha_is_read_back_from_the_source() {
        let s = "independent generator seed 7300 (lugre at 2× the noise, α = 1.250e-2)";
        assert_eq!(alpha_from_source(s), Some(0.0125));
    }

    #[test]
    fn a_false_none_counts_only_above_the_limit() {
        let mut s = LimitScore::default();
        s.add("a", "none", Some(0.8), false, false);
        s.add("b", "none", Some(1.2), false, false);
        s.add("c", "friction", Some(2.0), true, false);
        s.add("d", "unexplained", Some(3.0), false, true);
        s.add("e", "none", None, false, false);
        assert_eq!(s.false_none_above.len(), 1);
        assert_eq!(s.at_1_5, (2, 1));
        assert_eq!(s.closest_at_1_5, 1);
        assert_eq!(s.not_scored, vec!["e".to_string()]);
    }
}
