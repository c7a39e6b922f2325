//! The sink of the diagnosis: the phases' results assembled into the [`Diagnosis`].

use super::*;

/// Every phase's result, by value: the report is the sink and moves the traces into the
/// [`Diagnosis`].
pub(super) struct Phases<'a> {
    pub(super) nom: NominalPhase<'a>,
    pub(super) lp: LoopPhase<'a>,
    pub(super) rf: RefitPhase,
    /// The kept search ([`GreyPhase::kept`]).
    pub(super) search: SearchPhase,
    /// The kept residual test ([`GreyPhase::kept`]).
    pub(super) resid: ResidualPhase,
    pub(super) closest: ClosestPhase,
    pub(super) grey: GreyPhase,
    pub(super) limits: LimitsPhase,
    pub(super) reloop: ReloopPhase,
}

/// The plain-words summary and the result.
pub(super) fn assemble(inp: &Inputs<'_>, p: Phases<'_>) -> Diagnosis {
    let Phases {
        nom,
        lp,
        rf,
        mut search,
        resid,
        closest: ClosestPhase(closest),
        grey,
        limits,
        reloop,
    } = p;
    let sensor_offsets = sensor_offsets(inp.rec, &resid.ext_val_sim, inp.opts);
    let gain = 1.0 - resid.ext_err.overall / nom.nom_err.overall;
    let Settled {
        cause,
        status,
        greybox,
        beaten_by_baseline,
        final_hyp,
        dropped,
    } = settle_cause(
        (&nom, &rf, &resid),
        &grey,
        &reloop,
        &search.accepted,
        closest.as_ref(),
    );
    let law = greybox.as_ref().is_some_and(|g| g.accepted);
    let (extended, ext_fit_sim, ext_val_sim) = final_models(
        &lp,
        &search.current,
        law.then_some(&final_hyp),
        resid.ext_val_sim,
    );
    let cands = ranked(std::mem::take(&mut search.candidates));
    let extended_at_bounds = at_bounds(&search.current);
    let summary = edge_summary(
        write_summary(
            &nom,
            &rf,
            &search,
            &cands,
            &resid.ext_err,
            gain,
            &resid.test,
            &cause,
            greybox.as_ref(),
            dropped.as_ref(),
            beaten_by_baseline,
            &extended_at_bounds,
        ),
        closest.as_ref(),
        status,
        dropped.is_some(),
    );
    let warnings = record_warnings(inp.rec, inp.val, &nom);
    let d = Diagnosis {
        cause,
        status: status.to_string(),
        closest,
        detection_limits: BTreeMap::new(),
        next_tests: Vec::new(),
        causes: ids(&search.accepted),
        variants: variants_of(&search.current),
        nrmse_nominal: nom.nom_err,
        nrmse_refit: rf.refit_err,
        nrmse_extended: resid.ext_err,
        nrmse_baseline: nom.nrmse_baseline,
        baseline: nom.baseline,
        residual_test: resid.test,
        integration: nom.integration,
        greybox,
        gain,
        noise_floor: rf.noise_floor,
        candidates: cands,
        extended_params: params_of(&final_hyp),
        identified_loop: None,
        refit_at_bounds: at_bounds(&rf.h0),
        extended_at_bounds,
        sensor_offsets,
        ambiguities: search.ambiguities,
        refit_continued: search.rebased,
        dropped_effects: dropped,
        beaten_by_baseline,
        warnings,
        analysis: nom.analysis,
        analysis_refit: rf.analysis_refit,
        split: nom.split,
        summary,
        extended,
        traces: Traces {
            nominal: Some(nom.nom_sim),
            extended: ext_fit_sim,
            validation: inp.val.map(|_| (nom.nom_val_sim, ext_val_sim)),
            split_index: nom.n_fit,
        },
    };
    finish(d, inp.nominal, limits, reloop.identified_loop)
}

/// The diagnosis with the detection limits (named in the summary of a `none`), the config's
/// own uncertainty in the extended config (the loop's was spent here) and the identified
/// loop.
fn finish(
    mut d: Diagnosis,
    config: &PlantParams,
    LimitsPhase(limits): LimitsPhase,
    identified_loop: Option<crate::loopid::IdentifiedLoop>,
) -> Diagnosis {
    if d.cause == "none" && !limits.is_empty() {
        d.summary = format!(
            "{} No effect above these detection limits (smallest size this record would have revealed; the loosest: {}).",
            d.summary,
            crate::limits::loosest(&limits, 3).join("; ")
        );
    }
    d.detection_limits = limits;
    d.extended.uncertainty = config.uncertainty.clone();
    if let Some(l) = &identified_loop {
        d.summary = format!("{} {}", d.summary, l.text);
    }
    d.identified_loop = identified_loop;
    d
}

/// Nominal parameters that ended within 0.5 % of the span from a bound of their stated
/// uncertainty: evidence of a missing effect (or of a wrong nominal value or uncertainty).
pub(super) fn at_bounds(h: &Hyp) -> Vec<String> {
    h.params
        .iter()
        .zip(&h.values)
        .filter(|(p, _)| !p.name.starts_with("effects."))
        .filter_map(|(p, v)| {
            let u = p.to_unit(*v);
            let side = if u <= 0.005 {
                "lower"
            } else if u >= 0.995 {
                "upper"
            } else {
                return None;
            };
            Some(format!(
                "{} = {:.4} at its {side} bound [{:.4}, {:.4}]",
                p.name, v, p.lo, p.hi
            ))
        })
        .collect()
}

/// The recommended model's plant parameters, its replay of the fitting record and its
/// held-out replay: of `law` (the catalogue model plus the grey-box law) when the law was
/// accepted, else of the catalogue model `current`, whose held-out replay the residual test
/// made (`catalogue_val_sim`).
fn final_models(
    lp: &LoopPhase<'_>,
    current: &Hyp,
    law: Option<&Hyp>,
    catalogue_val_sim: Replay,
) -> (PlantParams, Option<Replay>, Replay) {
    let (ctx, nominal) = (&lp.ctx, &lp.nominal);
    let h = law.unwrap_or(current);
    (
        h.build(nominal),
        ctx.fit_replay(&h.build(&ctx.fit_base)).ok(),
        law.map_or(catalogue_val_sim, |h| ctx.val_errors(h).1),
    )
}

/// The ids of `effects`, in order.
pub(super) fn ids(effects: &[EffectId]) -> Vec<String> {
    effects.iter().map(|e| e.as_str().to_string()).collect()
}

/// Sensor offsets of replay `sim` per channel column (SI unit of each channel); empty when
/// `opts.sensor_offsets` is off.
pub(super) fn sensor_offsets(rec: &Record, sim: &Replay, opts: &Options) -> BTreeMap<String, f64> {
    if opts.sensor_offsets {
        rec.channels
            .iter()
            .zip(&sim.offsets)
            .map(|(c, b)| (c.kind.column().to_string(), *b))
            .collect()
    } else {
        BTreeMap::new()
    }
}

/// The tested candidates, the accepted ones first, each group by ascending score.
pub(super) fn ranked(candidates: BTreeMap<EffectId, Candidate>) -> Vec<Candidate> {
    let mut cands: Vec<Candidate> = candidates.into_values().collect();
    cands.sort_by(|a, b| {
        b.accepted
            .cmp(&a.accepted)
            .then(a.score.total_cmp(&b.score))
    });
    cands
}

/// The records' own warnings (the held-out record's when it is another file), then the
/// integration check's.
pub(super) fn record_warnings(
    rec: &Record,
    val: Option<&Record>,
    nom: &NominalPhase<'_>,
) -> Vec<String> {
    rec.warnings
        .iter()
        .chain(if val.is_some() {
            nom.val_rec.warnings.iter()
        } else {
            [].iter()
        })
        .cloned()
        .chain(integration_warning(&nom.integration))
        .collect()
}

/// Structural variant of each effect of `h` (effect id → variant).
pub(super) fn variants_of(h: &Hyp) -> BTreeMap<String, String> {
    h.effects
        .iter()
        .zip(&h.variants)
        .map(|(e, v)| (e.as_str().to_string(), v.to_string()))
        .collect()
}

/// Parameters of `h` (dotted path → value).
pub(super) fn params_of(h: &Hyp) -> BTreeMap<String, f64> {
    h.params
        .iter()
        .zip(&h.values)
        .map(|(p, v)| (p.name.clone(), *v))
        .collect()
}

/// The cause once the grey-box law has had its say: what [`assemble`] names.
pub(super) struct Settled {
    pub(super) cause: String,
    /// The diagnosis' status for `cause` ([`status_of`]).
    pub(super) status: &'static str,
    pub(super) greybox: Option<crate::greybox::GreyBox>,
    /// Neither the catalogue model nor the law predicts the held-out part as well as ARX.
    pub(super) beaten_by_baseline: bool,
    /// The recommended model's hypothesis (the loop's second look's).
    pub(super) final_hyp: Hyp,
    /// The grey-box phase's dropped catalogue effects.
    pub(super) dropped: Option<DroppedEffects>,
}

/// Settles the cause of the residual test (`cause`) against the grey-box phase `grey`: an
/// accepted law that beats the catalogue model names it (judged on its figures before the
/// loop's second look); a catalogue model that loses to ARX (or whose effects were dropped)
/// with no law beating ARX either (the law as `reloop` scored it afresh) is `unexplained`;
/// then the closest catalogue effect (`closest`) has its say ([`edge_cause`]).
pub(super) fn settle_cause(
    (nom, rf, resid): (&NominalPhase<'_>, &RefitPhase, &ResidualPhase),
    grey: &GreyPhase,
    reloop: &ReloopPhase,
    accepted: &[EffectId],
    closest: Option<&crate::edge::Closest>,
) -> Settled {
    let (cause, ext_err) = (resid.cause.clone(), &resid.ext_err);
    // A grey-box law that carries the gain (its held-out error below the catalogue model's) is
    // the cause, named in physical terms, not `unexplained`.
    let cause = match grey.greybox.as_ref() {
        Some(g)
            if g.accepted
                && cause == "unexplained"
                && g.nrmse_validation.overall < ext_err.overall =>
        {
            g.cause().unwrap_or(cause)
        }
        _ => cause,
    };
    let (final_hyp, greybox) = (reloop.final_hyp.clone(), reloop.greybox.clone());
    // A catalogue model that loses to the linear black box, with no law that beats it either,
    // is not an explanation whatever was accepted on the fitting part.
    let arx = nom.nrmse_baseline.overall;
    let best = greybox
        .as_ref()
        .filter(|g| g.accepted)
        .map_or(ext_err.overall, |g| g.nrmse_validation.overall);
    let dropped = grey.dropped.clone();
    let catalogue_beaten = dropped.is_some() || (!accepted.is_empty() && ext_err.overall > arx);
    let beaten_by_baseline = catalogue_beaten && best > arx;
    let cause = if beaten_by_baseline {
        "unexplained".to_string()
    } else {
        cause
    };
    let cause = edge_cause(
        cause,
        closest,
        dropped.is_some(),
        greybox.as_ref(),
        &floors_by_column(nom, rf),
    );
    Settled {
        status: status_of(&cause, closest, dropped.is_some()),
        cause,
        greybox,
        beaten_by_baseline,
        final_hyp,
        dropped,
    }
}

/// The cause once the closest catalogue effect (`closest`, [`closest_fit`]) is known not to
/// explain the record: while it is still the cause (no grey-box law replaced it, `dropped`
/// false), the accepted grey-box law on top of it is the cause when that leaves no channel
/// far above its floor (`floors`), else the answer is `unexplained`.
pub(super) fn edge_cause(
    cause: String,
    closest: Option<&crate::edge::Closest>,
    dropped: bool,
    greybox: Option<&crate::greybox::GreyBox>,
    floors: &[(String, f64)],
) -> String {
    match closest {
        Some(c) if !dropped && cause == c.effect => greybox
            .filter(|g| {
                g.accepted && crate::edge::far_channels(&g.nrmse_validation, floors).is_empty()
            })
            .and_then(|g| g.cause())
            .unwrap_or_else(|| "unexplained".to_string()),
        _ => cause,
    }
}

/// The diagnosis' status (see [`Diagnosis::status`]) for `cause`.
pub(super) fn status_of(
    cause: &str,
    closest: Option<&crate::edge::Closest>,
    dropped: bool,
) -> &'static str {
    match (cause, closest) {
        ("none", _) => "none",
        ("unexplained", Some(c)) if !dropped => {
            if c.at_edge {
                "edge_fit"
            } else {
                "not_explained"
            }
        }
        ("unexplained", _) => "unexplained",
        _ => "explained",
    }
}
