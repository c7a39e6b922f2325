//! Phase 1 of the diagnosis: the split, the replay's integration and the configured-step
//! shortcut, the nominal replay and its residual analysis, the ARX baseline.

use super::*;

/// Smallest noise floor of channel `kind` with measured values `y` (NRMSE units, -): the
/// quantisation noise of a position transducer with a declared resolution q (uniform error,
/// rms q/√12: a replay that differs by rounding flips samples across a step at rest, where the
/// PSD estimate of the floor sees no noise at all), and never below [`NUMERICAL_FLOOR`].
pub(super) fn quantisation_floor(
    kind: crate::data::ChannelKind,
    p: &PlantParams,
    y: &[f64],
) -> f64 {
    let q = match kind {
        crate::data::ChannelKind::Position => p.sensors.position.resolution,
        _ => 0.0,
    };
    (q / 12f64.sqrt() / std(y).max(1e-300)).max(NUMERICAL_FLOOR)
}

/// What the nominal phase hands on.
pub(super) struct NominalPhase<'a> {
    pub(super) ctx: Ctx<'a>,
    pub(super) n_fit: usize,
    pub(super) val_rec: &'a Record,
    pub(super) val_range: std::ops::Range<usize>,
    pub(super) split: String,
    pub(super) integration: crate::replay::IntegrationCheck,
    pub(super) nom_sim: Replay,
    pub(super) nom_val_sim: Replay,
    pub(super) analysis: Analysis,
    pub(super) nom_err: Errors,
    pub(super) baseline: Baseline,
    pub(super) nrmse_baseline: Errors,
}

impl<'a> Phase<'a> for NominalPhase<'a> {
    type Needs<'p>
        = ()
    where
        'a: 'p;

    fn run(inp: &Inputs<'a>, (): ()) -> Result<Self, String> {
        phase_nominal(inp.nominal, inp.rec, inp.val, inp.opts)
    }
}

/// Phase 1: split the data, choose the replay's integration (its own error must sit well
/// below the noise floor, or it is taken for a model error: a clean record was once answered
/// `line_dynamics`), replay the nominal model, analyse its residual, fit the ARX baseline.
fn phase_nominal<'a>(
    nominal: &PlantParams,
    rec: &'a Record,
    val: Option<&'a Record>,
    opts: &Options,
) -> Result<NominalPhase<'a>, String> {
    nominal.refit_ranges().map_err(|e| e.to_string())?;
    let (n_fit, val_rec, val_range, split) = split_data(rec, val, opts)?;
    let split = format!("{split}; {}", opts.drive.describe());
    let n_cost = n_fit.min(opts.max_fit_samples.max(100));
    let (fit_base, integration) = crate::replay::choose_integration_between(
        &replay_params(nominal, rec),
        rec,
        n_cost,
        opts.drive,
        opts.integration_min_cost,
        opts.integration_max_cost,
    );
    let mut val_base = replay_params(nominal, val_rec);
    val_base.integration = fit_base.integration.clone();
    let (fit_base, val_base, integration, drive, split) =
        match configured_step_explains(nominal, rec, val_rec, val_range.clone(), opts.drive) {
            Some((f, v, d)) => (
                f,
                v,
                crate::replay::IntegrationCheck {
                    configured_step_explains: true,
                    ..integration
                },
                d,
                configured_step_split(split, opts.drive, d),
            ),
            None => (fit_base, val_base, integration, opts.drive, split),
        };
    let sd_fit: Vec<f64> = rec
        .channels
        .iter()
        .map(|c| std(&c.values[..n_cost]).max(1e-300))
        .collect();
    let split = if n_cost < n_fit {
        format!("{split}; the fit cost uses the first {n_cost} samples of the fitting part")
    } else {
        split
    };
    let ctx = Ctx {
        fit_rec: rec,
        fit_base,
        n_fit: n_cost,
        val_rec,
        val_base,
        val_range: val_range.clone(),
        sd_fit,
        drive,
        offsets: opts.sensor_offsets,
        cost_channel: None,
        max_substeps: integration.config_substeps.max(integration.substeps),
    };
    let nom_sim = ctx
        .fit_replay(&ctx.fit_base)
        .map_err(|e| format!("nominal config cannot be replayed: {e}"))?;
    let analysis = analyse(rec, &nom_sim, 0..n_fit);
    let (nom_err, nom_val_sim) = ctx.val_errors(&Hyp::empty());
    let (baseline, nrmse_baseline) = fit_baseline(rec, val_rec, val_range.clone(), n_fit, opts);
    Ok(NominalPhase {
        ctx,
        n_fit,
        val_rec,
        val_range,
        split,
        integration,
        nom_sim,
        nom_val_sim,
        analysis,
        nom_err,
        baseline,
        nrmse_baseline,
    })
}

/// The fitting part's length, the held-out record and its range, and the split's account:
/// all of `rec` against `val`, or `rec`'s last `opts.holdout` held out (at least 10 samples
/// on each side).
pub(super) fn split_data<'a>(
    rec: &'a Record,
    val: Option<&'a Record>,
    opts: &Options,
) -> Result<(usize, &'a Record, std::ops::Range<usize>, String), String> {
    let n = rec.len();
    Ok(match val {
        Some(v) => (
            n,
            v,
            0..v.len(),
            format!(
                "fit on {} ({} samples), validated on {} ({} samples)",
                rec.source,
                n,
                v.source,
                v.len()
            ),
        ),
        None => {
            let nf = ((1.0 - opts.holdout) * n as f64).round() as usize;
            if nf < 10 || n - nf < 10 {
                return Err(format!(
                    "{}: {n} samples are too few to hold out {:.0} %",
                    rec.source,
                    opts.holdout * 100.0
                ));
            }
            (nf, rec, nf..n, format!("first {nf} samples ({:.3} s) for fitting, last {} ({:.3} s) held out; the held-out part is replayed continuously from the start", nf as f64 * rec.dt, n - nf, (n - nf) as f64 * rec.dt))
        }
    })
}

/// The split's account once the configured step explains the data with drive `used`
/// (configured: `configured`): it says so when the recorded command replaced the rig's loop.
pub(super) fn configured_step_split(split: String, configured: Drive, used: Drive) -> String {
    match (configured, used) {
        (a, Drive::Recorded) if a.closed_loop() => format!(
            "{split}; the open-loop replay of the recorded command `u` reproduces the data at the config's own step, so it is used instead (the rig's loop acted on measured, noisy signals the closed-loop replay does not have)"
        ),
        _ => split,
    }
}

/// Black-box baseline fitted on the first `n_fit` samples of `rec` and its held-out NRMSE on
/// `val_range` of `val_rec` (input: the recorded command, or the setpoint when the rig's own
/// loop is replayed).
pub(super) fn fit_baseline(
    rec: &Record,
    val_rec: &Record,
    val_range: std::ops::Range<usize>,
    n_fit: usize,
    opts: &Options,
) -> (Baseline, Errors) {
    let (input, input_name) = match (opts.drive, &rec.reference) {
        (d, Some(r)) if d.closed_loop() => (r.clone(), "ref"),
        _ => (rec.u.clone(), "u"),
    };
    let baseline = crate::baseline::fit(rec, &input, n_fit, input_name);
    let val_input = match (opts.drive, &val_rec.reference) {
        (d, Some(r)) if d.closed_loop() => r.clone(),
        _ => val_rec.u.clone(),
    };
    let ch = crate::baseline::score(&baseline, val_rec, &val_input, val_range);
    let v: Vec<f64> = ch.values().copied().collect();
    let nrmse_baseline = Errors {
        overall: overall(&v),
        channels: ch,
    };
    (baseline, nrmse_baseline)
}

/// The nominal model replayed at the config's own integration (no refinement: substeps as
/// `ehactl run` takes them, automatic where the config says so): when its held-out residual
/// is at its noise floor **and** white on every channel (level ≤ 1, or Ljung–Box below
/// [`SHORTCUT_LB_CRIT`] and level ≤ [`SHORTCUT_LEVEL`]), returns the fit and validation
/// parameters to keep.
/// Either failing sends the record to the full search: a residual 1.2–6× its floor but
/// thousands of Ljung–Box units from white is a real effect, not noise (an outside
/// generator's hidden effects were once answered `none` here on the level test alone). A
/// record of the config's own run is reproduced this way up to its sensor noise; a replay at
/// a finer step differs from it by the run's integration error, which the diagnosis would
/// otherwise report as a model discrepancy.
pub(super) fn configured_step_explains(
    nominal: &PlantParams,
    rec: &Record,
    val_rec: &Record,
    val_range: std::ops::Range<usize>,
    drive: Drive,
) -> Option<(PlantParams, PlantParams, Drive)> {
    let fit = replay_params(nominal, rec);
    let val = replay_params(nominal, val_rec);
    // The configured drive first; for a closed-loop replay also the recorded command, which
    // carries what the rig's loop did with its noisy measurements.
    let mut drives = vec![drive];
    if drive.closed_loop() {
        drives.push(Drive::Recorded);
    }
    drives
        .into_iter()
        .find(|d| reproduces(&val, val_rec, val_range.clone(), *d))
        .map(|d| (fit, val, d))
}

/// Whether the replay of `val_rec` with `p` and `drive` leaves a held-out residual that is
/// noise on every channel (see [`configured_step_explains`]).
pub(super) fn reproduces(
    p: &PlantParams,
    val_rec: &Record,
    val_range: std::ops::Range<usize>,
    drive: Drive,
) -> bool {
    let Ok(sim) = replay_with(p, val_rec, val_rec.len(), drive) else {
        return false;
    };
    if sim.failed {
        return false;
    }
    let floor: Vec<f64> = val_rec
        .channels
        .iter()
        .zip(&sim.y)
        .map(|(c, yh)| {
            let y = &c.values[val_range.clone()];
            crate::replay::residual_floor(y, &yh[val_range.clone()])
                .max(quantisation_floor(c.kind, p, y))
        })
        .collect();
    crate::residual::test(
        "nominal",
        val_rec,
        &sim,
        val_range,
        &floor,
        crate::residual::LEVEL_SOFT,
    )
    .channels
    .iter()
    .all(|c| c.level <= 1.0 || (c.ljung_box <= SHORTCUT_LB_CRIT && c.level <= SHORTCUT_LEVEL))
}
