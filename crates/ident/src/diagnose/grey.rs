//! Phase 7: the grey-box law when the catalogue is exhausted.

use super::*;

/// Share of a weak catalogue winner's held-out J (NRMSE²) the grey-box law alone must stay
/// below to replace it (-): the ≥ 10 % a candidate must gain to be accepted (step 7).
pub(super) const WEAK_LAW_J_SHARE: f64 = 0.9;

/// What the grey-box phase hands on.
pub(super) struct GreyPhase {
    /// The recommended model's hypothesis (the catalogue model, plus the law when accepted).
    pub(super) final_hyp: Hyp,
    pub(super) greybox: Option<crate::greybox::GreyBox>,
    pub(super) dropped: Option<DroppedEffects>,
    /// When the law alone wins: the search and the residual test of the nominal refit, which
    /// replace the catalogue model's for every later phase ([`GreyPhase::kept`]).
    pub(super) replaced: Option<(SearchPhase, ResidualPhase)>,
}

impl<'a> Phase<'a> for GreyPhase {
    type Needs<'p>
        = (
        &'p NominalPhase<'a>,
        &'p LoopPhase<'a>,
        &'p RefitPhase,
        &'p SearchPhase,
        &'p ResidualPhase,
        &'p ClosestPhase,
    )
    where
        'a: 'p;

    fn run(
        inp: &Inputs<'a>,
        (nom, lp, rf, search, resid, closest): Self::Needs<'_>,
    ) -> Result<Self, String> {
        let env = GreyEnv {
            nom,
            ctx: &lp.ctx,
            rf,
            opts: inp.opts,
        };
        Ok(phase_greybox(&env, search, resid, closest.0.as_ref()))
    }
}

impl GreyPhase {
    /// The search and residual test the phases after this one read: the refit's when the law
    /// alone won, else `search` and `resid` as they were.
    pub(super) fn kept(
        &self,
        search: SearchPhase,
        resid: ResidualPhase,
    ) -> (SearchPhase, ResidualPhase) {
        self.replaced.clone().unwrap_or((search, resid))
    }
}

/// What the grey-box phase reads of the earlier phases and the settings.
struct GreyEnv<'s, 'a> {
    nom: &'s NominalPhase<'a>,
    ctx: &'s Ctx<'a>,
    rf: &'s RefitPhase,
    opts: &'s Options,
}

/// Phase 5: a grey-box law when the catalogue model's held-out residual is not noise, fitted
/// on top of it. A catalogue extension that predicts the held-out part worse than the ARX
/// baseline is weak evidence (on a damper whose force tracks velocity, a mount's compliance
/// was once accepted while a linear black box predicted twice as well), and so is one whose
/// round winner was weak ([`weak_winner`]: on a damper of 1150 N yield force, a mount of
/// 200 kg, at its range's end, explaining 37 % of the error): the law then competes on the
/// nominal refit alone, scored on the same held-out part, and the better model is kept.
/// When the law alone wins, the refit's search and residual test replace `search` and
/// `resid` ([`GreyPhase::replaced`]).
fn phase_greybox(
    env: &GreyEnv<'_, '_>,
    search: &SearchPhase,
    resid: &ResidualPhase,
    closest: Option<&crate::edge::Closest>,
) -> GreyPhase {
    let (nom, rf, opts) = (env.nom, env.rf, env.opts);
    let mut out = GreyPhase {
        final_hyp: search.current.clone(),
        greybox: None,
        dropped: None,
        replaced: None,
    };
    if !opts.greybox || resid.test.noise {
        return out;
    }
    let arx = nom.nrmse_baseline.overall;
    let extend = |h: &Hyp, c: f64| {
        crate::greybox::extend(env.ctx, h, c, &rf.scales, arx, opts.evals_per_param)
    };
    let (h, g) = extend(&search.current, search.cur_train);
    let with_law = g.accepted.then_some(g.nrmse_validation.overall);
    let catalogue = resid.ext_err.overall;
    if let Some(h) = h {
        out.final_hyp = h;
    }
    out.greybox = Some(g);
    let weak: Vec<&str> = search
        .accepted
        .iter()
        .filter(|e| search.weak.contains(e))
        .map(|e| e.as_str())
        .collect();
    // Against a model ARX beats, any gain of the law decides; against a weak winner that
    // still beats ARX, the law must lower the held-out J (NRMSE²) as a candidate must to be
    // accepted (step 7, ≥ 10 %): on the Sjöberg record, an asymmetric spool limit that
    // explains 40 % of the error (0.458) is kept against a flow-gain asymmetry law (0.445).
    let (why, j_share) = if catalogue > arx {
        (format!("the catalogue model predicts the held-out part worse than the ARX baseline (NRMSE {catalogue:.4} vs {arx:.4})"), 1.0)
    } else if let Some(c) = closest {
        // On the footing of a catalogue candidate: the law must lower the held-out J by the
        // ≥ 10 % a candidate must (Sjöberg: a flow-gain asymmetry law 0.445 against the
        // closest effect, an asymmetric spool limit at 0.458, both leaving p_a at 15× its
        // floor: neither explains the record).
        (
            format!(
                "`{}` is weak evidence, only the closest catalogue effect ({}), and the law lowers the held-out J by at least {:.0} %",
                c.effect,
                c.reasons.join("; "),
                100.0 * (1.0 - WEAK_LAW_J_SHARE)
            ),
            WEAK_LAW_J_SHARE,
        )
    } else if !weak.is_empty() {
        (
            format!(
                "`{}` was weak evidence when accepted (see `ambiguities`), and the law lowers the held-out J by at least {:.0} %",
                weak.join("`, `"),
                100.0 * (1.0 - WEAK_LAW_J_SHARE)
            ),
            WEAK_LAW_J_SHARE,
        )
    } else {
        return out;
    };
    if search.accepted.is_empty() {
        return out;
    }
    let (hb, gb) = extend(&rf.h0, rf.c0_train);
    let kept = with_law.unwrap_or(catalogue);
    let wins = gb.nrmse_validation.overall.powi(2) < j_share * kept.powi(2);
    let Some(hb) = hb.filter(|_| wins) else {
        return out;
    };
    out.dropped = Some(DroppedEffects {
        effects: search
            .accepted
            .iter()
            .map(|e| e.as_str().to_string())
            .collect(),
        nrmse_catalogue: catalogue,
        nrmse_catalogue_with_law: with_law,
        nrmse_law: gb.nrmse_validation.overall,
        nrmse_baseline: arx,
        why,
    });
    let mut refit = search.clone();
    for c in refit.candidates.values_mut() {
        c.accepted = false;
    }
    refit.current = rf.h0.clone();
    refit.cur_train = rf.c0_train;
    refit.accepted.clear();
    let refit_resid = phase_residual_test(nom, env.ctx, rf, &refit);
    out.replaced = Some((refit, refit_resid));
    out.final_hyp = hb;
    out.greybox = Some(gb);
    out
}
