//! Phase 3: the nominal parameters refit within their stated uncertainty, the noise floor.

use super::*;

/// What the refit phase hands on.
pub(super) struct RefitPhase {
    pub(super) h0: Hyp,
    pub(super) c0_train: f64,
    pub(super) refit_err: Errors,
    /// Noise floor per channel (NRMSE units), incl. the replay's remaining integration error.
    pub(super) floor_ch: Vec<f64>,
    pub(super) noise_floor: f64,
    pub(super) analysis_refit: Analysis,
    pub(super) scales: Scales,
    /// Something was fitted before the search (a nominal parameter, an assumed loop), or the
    /// configured step explained the record (its shortcut's own test has judged it): the soft
    /// level of the final test ([`crate::residual::LEVEL_SOFT`]) excuses the colour a fit leaves.
    pub(super) fitted: bool,
}

impl<'a> Phase<'a> for RefitPhase {
    type Needs<'p>
        = (&'p NominalPhase<'a>, &'p LoopPhase<'a>)
    where
        'a: 'p;

    /// The model as configured reproduces the data within the noise: nothing to refit (a
    /// refit could only fit the noise).
    fn run(inp: &Inputs<'a>, (nom, lp): Self::Needs<'_>) -> Result<Self, String> {
        Ok(phase_refit(
            nom,
            &lp.ctx,
            &lp.nominal,
            inp.opts,
            inp.bar(),
            !nom.integration.configured_step_explains,
            lp.identified.is_some(),
        ))
    }
}

/// Phase 3: refit the nominal parameters alone within their stated uncertainty (the
/// reference every effect must beat), estimate the noise floor from its held-out residual.
fn phase_refit(
    nom: &NominalPhase<'_>,
    ctx: &Ctx<'_>,
    nominal: &PlantParams,
    opts: &Options,
    bar: &Tracker,
    refit: bool,
    loop_fitted: bool,
) -> RefitPhase {
    let base = base_params(nominal);
    let h0 = Hyp {
        effects: vec![],
        variants: vec![],
        values: base.iter().map(|p| p.init).collect(),
        params: base,
    };
    let (h0, c0_train) = if refit {
        // A simplex that stopped short leaves a coloured residual on a clean record, which the
        // final test cannot call noise: a larger budget, restarted while it improves.
        let budget = opts.evals_per_param * REFIT_BUDGET;
        let (mut h, mut c) = ctx.fit(h0, usize::MAX, budget);
        for _ in 0..REFIT_RESTARTS {
            let (h2, c2) = ctx.fit(h.clone(), usize::MAX, budget);
            if c2 >= c {
                break;
            }
            (h, c) = (h2, c2);
        }
        (h, c)
    } else {
        let e = errors(ctx.fit_rec, &nom.nom_sim, 0..nom.n_fit);
        (h0, e.overall * e.overall)
    };
    bar.inc();
    let (refit_err, refit_val_sim) = ctx.val_errors(&h0);
    // Noise floor from the refit model's held-out residual (signal content removed); the
    // PSD median over the upper half band ignores narrow lines and slow model error. The
    // replay's own integration error that the chosen substeps leave (step halving:
    // ≈ 2 × the N-vs-2N difference for a first-order scheme) is added in quadrature, so that
    // it can be blamed neither on an effect nor on `unexplained`.
    let floor_ch = channel_floors(nom, nominal, &refit_val_sim);
    let noise_floor = overall(&floor_ch);
    let fitted = !refit || loop_fitted || !h0.params.is_empty();
    // Residual analysis of the refit model: what is left once parameter errors are absorbed.
    // Its findings are the evidence and the start values of the effect fits.
    let analysis_refit = match ctx.fit_replay(&h0.build(&ctx.fit_base)) {
        Ok(sim) => analyse(ctx.fit_rec, &sim, 0..nom.n_fit),
        Err(_) => nom.analysis.clone(),
    };
    RefitPhase {
        h0,
        c0_train,
        refit_err,
        floor_ch,
        noise_floor,
        fitted,
        analysis_refit,
        scales: Scales::new(nominal, ctx.fit_rec),
    }
}

/// Noise floor per channel (NRMSE units) from the held-out residual of the model replayed in
/// `sim`: its white-noise level (the PSD median over the upper half band, which ignores narrow
/// lines and slow model error), the replay's own integration error that the chosen substeps
/// leave (step halving: ≈ 2 × the N-vs-2N difference for a first-order scheme) in quadrature,
/// so that it can be blamed neither on an effect nor on `unexplained`, and never below the
/// quantisation floor.
pub(super) fn channel_floors(
    nom: &NominalPhase<'_>,
    nominal: &PlantParams,
    sim: &Replay,
) -> Vec<f64> {
    let vr = nom.val_range.clone();
    nom.val_rec
        .channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| {
            let y = &c.values[vr.clone()];
            let f = crate::replay::residual_floor(y, &yh[vr.clone()]);
            let ig = if nom.integration.met || nom.integration.configured_step_explains {
                0.0
            } else {
                2.0 * nom
                    .integration
                    .error
                    .get(c.kind.column())
                    .copied()
                    .unwrap_or(0.0)
            };
            f.hypot(ig).max(quantisation_floor(c.kind, nominal, y))
        })
        .collect()
}
