//! The diagnosis' plain-words summary.

use super::*;

/// The whole summary: its opening, the residual test's sentence, the closing sentences.
#[allow(clippy::too_many_arguments)]
pub(super) fn write_summary(
    nom: &NominalPhase<'_>,
    rf: &RefitPhase,
    search: &SearchPhase,
    cands: &[Candidate],
    ext_err: &Errors,
    gain: f64,
    residual_test: &crate::residual::ResidualTest,
    cause: &str,
    greybox: Option<&crate::greybox::GreyBox>,
    dropped: Option<&DroppedEffects>,
    beaten_by_baseline: bool,
    extended_at_bounds: &[String],
) -> String {
    let summary = opening_summary(
        nom,
        rf,
        &search.accepted,
        cands,
        ext_err,
        gain,
        &search.ambiguities,
        &search.rebased,
    );
    let mut summary = with_residual_sentence(
        summary,
        residual_test,
        &search.accepted,
        cause,
        greybox,
        rf,
        nom,
    );
    closing_sentences(
        &mut summary,
        dropped,
        beaten_by_baseline,
        ext_err,
        greybox,
        nom.nrmse_baseline.overall,
        extended_at_bounds,
    );
    summary
}

/// The summary's opening: the configured-step shortcut's `none`, or the search's account of
/// what it accepted, with every move of the current model during the search (`rebased`).
#[allow(clippy::too_many_arguments)]
pub(super) fn opening_summary(
    nom: &NominalPhase<'_>,
    rf: &RefitPhase,
    accepted: &[EffectId],
    cands: &[Candidate],
    ext_err: &Errors,
    gain: f64,
    ambiguities: &[String],
    rebased: &[String],
) -> String {
    let mut summary = if nom.integration.configured_step_explains {
        format!(
            "The nominal model as configured, replayed at the config's own integration step, reproduces the held-out data within the noise (held-out NRMSE {:.4}, estimated noise floor {:.4}); nothing was refitted or added. The answer is `none`.",
            nom.nom_err.overall, rf.noise_floor
        )
    } else {
        summary_text(
            accepted,
            cands,
            &rf.analysis_refit,
            &nom.nom_err,
            &rf.refit_err,
            ext_err,
            gain,
            rf.noise_floor,
            ambiguities,
        )
    };
    for r in rebased {
        summary.push_str(&format!(" The refit went on during the search: {r}."));
    }
    summary
}

/// `summary` with the residual test's sentence when the final model's held-out residual is
/// not noise: per channel its level and whiteness, and the signature, worded for a law that
/// carries the cause, for `unexplained`, or after accepted effects.
pub(super) fn with_residual_sentence(
    mut summary: String,
    residual_test: &crate::residual::ResidualTest,
    accepted: &[EffectId],
    cause: &str,
    greybox: Option<&crate::greybox::GreyBox>,
    rf: &RefitPhase,
    nom: &NominalPhase<'_>,
) -> String {
    if let Some(sig) = &residual_test.signature {
        let lv: Vec<String> = residual_test
            .channels
            .iter()
            .map(|c| {
                format!(
                    "`{}` {:.1}× floor, Ljung–Box Q {:.0}{}",
                    c.channel,
                    c.level,
                    c.ljung_box,
                    if c.white { " (white)" } else { "" }
                )
            })
            .collect();
        summary = if accepted.is_empty() && cause != "unexplained" {
            let g = greybox.map_or(0.0, |g| g.nrmse_validation.overall);
            format!(
                "No catalogue effect explains the discrepancy (after refitting the nominal parameters within their uncertainty the held-out NRMSE is {:.4}, noise floor {:.4}; the catalogue model's held-out residual is not noise: {}. Signature: {}). The grey-box law does: the cause is {cause}; with it the held-out NRMSE is {g:.4} (ARX baseline {:.4}).",
                rf.refit_err.overall, rf.noise_floor, lv.join("; "), sig.text, nom.nrmse_baseline.overall
            )
        } else if accepted.is_empty() {
            format!(
                "The answer is `unexplained`, not `none`: no catalogue effect explains the discrepancy (after refitting the nominal parameters within their uncertainty the held-out NRMSE is {:.4}, noise floor {:.4}), and the held-out residual is not noise ({}). Signature: {}.",
                rf.refit_err.overall, rf.noise_floor, lv.join("; "), sig.text
            )
        } else {
            format!(
                "{summary} The remaining held-out residual is still not noise ({}): {}.",
                lv.join("; "),
                sig.text
            )
        };
    }
    summary
}

/// The summary's closing sentences: the effects dropped for a grey-box law, a model that
/// loses to the ARX baseline (`arx`, held-out NRMSE), nominal parameters of the final model
/// on a bound of their uncertainty.
pub(super) fn closing_sentences(
    summary: &mut String,
    dropped: Option<&DroppedEffects>,
    beaten_by_baseline: bool,
    ext_err: &Errors,
    greybox: Option<&crate::greybox::GreyBox>,
    arx: f64,
    extended_at_bounds: &[String],
) {
    if let Some(d) = dropped {
        summary.push_str(&dropped_text(d));
    }
    if beaten_by_baseline {
        summary.push_str(&format!(
            " The answer is `unexplained`: neither the catalogue model (held-out NRMSE {:.4}) nor the grey-box law ({}) predicts the held-out part as well as the ARX baseline ({arx:.4}); extended.toml holds the better physical model.",
            dropped.map_or(ext_err.overall, |d| d.nrmse_catalogue),
            greybox
                .filter(|g| g.accepted)
                .map_or("no term accepted".to_string(), |g| format!("{:.4}", g.nrmse_validation.overall)),
        ));
    }
    if !extended_at_bounds.is_empty() {
        summary.push_str(&format!(
            " Nominal parameters of the final model on a bound of their stated uncertainty (evidence of a missing effect, or of a wrong nominal value): {}.",
            extended_at_bounds.join("; ")
        ));
    }
}

/// The summary opened by what the closest catalogue effect (`closest`) does not explain, for
/// `status` `edge_fit` / `not_explained`, or beside the grey-box law that explains the rest
/// (`explained`, not `dropped`: the dropped effects have their own sentence).
pub(super) fn edge_summary(
    summary: String,
    closest: Option<&crate::edge::Closest>,
    status: &str,
    dropped: bool,
) -> String {
    let Some(c) = closest else {
        return summary;
    };
    let what = format!(
        "`{}`{}{}",
        c.effect,
        if c.variant == "-" {
            String::new()
        } else {
            format!(" (variant `{}`)", c.variant)
        },
        if c.at_edge {
            " at the edge of its range"
        } else {
            ""
        }
    );
    match status {
        "edge_fit" | "not_explained" => format!(
            "The record is not explained: the closest catalogue effect is {what} ({}), and it is not named as the cause. {}",
            c.reasons.join("; "),
            summary.replacen(
                "The simulation disagrees with the data mainly because of",
                "The closest catalogue model adds",
                1
            )
        ),
        "explained" if !dropped => format!(
            "The closest catalogue effect {what} does not explain the record alone ({}); the grey-box law on top of it does. {summary}",
            c.reasons.join("; ")
        ),
        _ => summary,
    }
}

/// The summary's sentence on catalogue effects dropped for a grey-box law.
pub(super) fn dropped_text(d: &DroppedEffects) -> String {
    let on_top = d.nrmse_catalogue_with_law.map_or(String::new(), |w| {
        format!(", {w:.4} with a grey-box law on top of them")
    });
    format!(
        " The catalogue effect(s) {} accepted on the fitting part had to compete with a grey-box law: {} (held-out NRMSE {:.4}, ARX baseline {:.4}{on_top}); the grey-box law on the nominal refit alone predicts it better ({:.4}), so they are not kept.",
        d.effects.join(" + "),
        d.why,
        d.nrmse_catalogue,
        d.nrmse_baseline,
        d.nrmse_law
    )
}

/// A warning when the replay's integration error could not be brought well below the noise
/// floor within the allowed cost, with the substeps that would (first-order scheme: the error
/// scales with the step).
pub(super) fn integration_warning(ig: &crate::replay::IntegrationCheck) -> Option<String> {
    if ig.met {
        return None;
    }
    let worst = ig
        .error
        .iter()
        .map(|(k, e)| (k, e / ig.floor.get(k).copied().unwrap_or(0.0).max(1e-12)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let need = (ig.substeps as f64 * worst.1 / ig.ratio_limit * 1.2).ceil();
    if ig.configured_step_explains {
        // First order: the error at the config's step is the chosen step's × the step ratio.
        let at_config = worst.1 * ig.substeps as f64 / ig.config_substeps.max(1) as f64;
        return Some(format!(
            "the nominal model at the config's own integration ({} substeps per sample) reproduces these data within the noise, so they were replayed at that step (as `ehactl run` steps it); its integration error there, ≈ {at_config:.1}× the noise floor on `{}`, would count against data of the physical rig: set [plant.integration] substeps = {need:.0} for a replay accurate to the noise (≈ {:.0}× the run time)",
            ig.config_substeps, worst.0, need / ig.config_substeps.max(1) as f64
        ));
    }
    Some(format!(
        "replay integration error on `{}` is {:.2}× its noise floor with {} substeps (required ≤ {}; the cost limit {}× the config's {} substeps was reached): it is counted as noise (added to the floor), so small effects may go undetected; set [plant.integration] substeps = {need:.0} in the config for an accurate replay (≈ {:.0}× the run time)",
        worst.0, worst.1, ig.substeps, ig.ratio_limit, ig.max_cost, ig.config_substeps, need / ig.config_substeps.max(1) as f64
    ))
}

#[allow(clippy::too_many_arguments)]
pub(super) fn summary_text(
    accepted: &[EffectId],
    cands: &[Candidate],
    an: &Analysis,
    nom: &Errors,
    refit: &Errors,
    ext: &Errors,
    gain: f64,
    floor: f64,
    amb: &[String],
) -> String {
    let mut s = String::new();
    if accepted.is_empty() {
        s.push_str(&format!(
            "No effect of the catalogue explains the discrepancy: after refitting the nominal parameters within their stated uncertainty the held-out NRMSE is {:.4} (nominal {:.4}, estimated noise floor {:.4}), and no added effect reduced it significantly. The answer is `none`.",
            refit.overall, nom.overall, floor
        ));
    } else {
        let names: Vec<&str> = accepted.iter().map(|e| e.as_str()).collect();
        s.push_str(&format!(
            "The simulation disagrees with the data mainly because of `{}`",
            names[0]
        ));
        if names.len() > 1 {
            s.push_str(&format!(
                " (then {})",
                names[1..]
                    .iter()
                    .map(|n| format!("`{n}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        s.push_str(". ");
        for e in accepted {
            if let Some(c) = cands.iter().find(|c| c.effect == e.as_str()) {
                s.push_str(&format!(
                    "Evidence for `{}`: {}. Fitted: {}. ",
                    c.effect,
                    c.evidence,
                    c.params
                        .iter()
                        .map(|(k, v)| format!("{k} = {v:.4e}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        s.push_str(&format!(
            "Adding {} cuts the held-out NRMSE from {:.4} (nominal) and {:.4} (nominal refit) to {:.4}, a gain of {:.1} % (noise floor ≈ {:.4}).",
            if names.len() > 1 { "these effects" } else { "this effect" },
            nom.overall, refit.overall, ext.overall, gain * 100.0, floor
        ));
    }
    if !an.tones.is_empty() && !accepted.contains(&EffectId::SensorTone) {
        s.push_str(&format!(
            " A narrow residual line at {:.1} Hz on `{}` was seen but not confirmed by the fit.",
            an.tones[0].frequency, an.tones[0].channel
        ));
    }
    for a in amb {
        s.push(' ');
        s.push_str(a);
    }
    s
}
