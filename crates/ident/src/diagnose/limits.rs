//! Phase 8: the detection limits of the catalogue effects not named ([`crate::limits`]),
//! each confirmed by injection and recovery: the effect added to the record itself at its
//! linearised limit and fitted under the search's own acceptance test.

use super::*;
use crate::limits::{DetectionLimit, Injection};

/// The smallest size of every catalogue effect tested and not named that this record would
/// have revealed (effect id → limit); empty when `Options::detection_limits` is off.
pub(super) struct LimitsPhase(pub(super) BTreeMap<String, DetectionLimit>);

impl<'a> Phase<'a> for LimitsPhase {
    type Needs<'p>
        = (
        &'p NominalPhase<'a>,
        &'p LoopPhase<'a>,
        &'p RefitPhase,
        &'p SearchPhase,
        &'p GreyPhase,
    )
    where
        'a: 'p;

    /// Judged on the recommended model (the grey-box phase's), for the effects the kept
    /// search did not accept.
    fn run(inp: &Inputs<'a>, (nom, lp, rf, search, grey): Self::Needs<'_>) -> Result<Self, String> {
        if !inp.opts.detection_limits {
            return Ok(LimitsPhase(BTreeMap::new()));
        }
        let not_named: Vec<EffectId> = inp
            .opts
            .effects
            .iter()
            .copied()
            .filter(|e| !search.accepted.contains(e))
            .collect();
        let linear = crate::limits::detection_limits(
            &lp.ctx,
            &grey.final_hyp,
            &rf.floor_ch,
            &not_named,
            &lp.nominal,
            &rf.scales,
            &rf.analysis_refit,
        );
        // When the configured step explains the record, no candidate was fitted: the check
        // would cost 10–20× the diagnosis (the Sirohi circuit's own log: 9 s → 178 s CPU),
        // so the limits stay linearised there (`method`).
        if nom.integration.configured_step_explains {
            return Ok(LimitsPhase(
                linear.into_iter().map(|(e, (l, _))| (e, l)).collect(),
            ));
        }
        let env = SearchEnv {
            nom,
            ctx: &lp.ctx,
            rf,
        };
        Ok(LimitsPhase(confirm_all(
            &env,
            &grey.final_hyp,
            linear,
            &search.candidates,
            inp.opts,
            inp.bar(),
        )))
    }
}

/// Every linearised limit of `linear` confirmed or raised ([`confirm`]), the effects in
/// parallel on the search's worker count. Only the loosest structure and shape of each
/// effect is checked: checking its three loosest took the diagnosis of the clean test bench
/// to 3.3× the one without limits (`diagnose_speed 101 none 1`), against 2.45× for one
/// before [`CHECK_BUDGET_SHARE`]; the linearised order already puts the shapes hardest to
/// see first (`limits::shapes`).
fn confirm_all(
    env: &SearchEnv<'_, '_>,
    model: &Hyp,
    linear: BTreeMap<String, (DetectionLimit, Option<Injection>)>,
    candidates: &BTreeMap<EffectId, Candidate>,
    opts: &Options,
    bar: &Tracker,
) -> BTreeMap<String, DetectionLimit> {
    let jobs: Vec<(String, DetectionLimit, Option<Injection>)> =
        linear.into_iter().map(|(e, (l, i))| (e, l, i)).collect();
    bar.add_stage(jobs.len() as u64, "detection limits".to_string());
    let order: Vec<usize> = (0..jobs.len()).collect();
    let checked = in_parallel(&jobs, &order, worker_threads(opts), bar, |(_, l, inj)| match inj {
        Some(inj) if l.limit.is_some() => {
            let fitted = fitted_values(inj, candidates.get(&inj.effect));
            let base = match &fitted {
                Some(v) => inj.with_values(model, v, None),
                None => model.clone(),
            };
            let at = |v: f64| match &fitted {
                Some(f) => inj.with_values(model, f, Some(v)),
                None => inj.added_to(model, v),
            };
            let trial = Trial { base: &base, at: &at };
            confirm(env, model, &trial, l.clone(), inj, opts.evals_per_param)
        }
        _ => l.clone(),
    });
    checked
        .into_iter()
        .map(|(i, l)| (jobs[i].0.clone(), l))
        .collect()
}

/// What an injection at a trial size adds to the record: the change from `base`'s replay
/// to that of `at(size)`. `base` is the model with the structure as the search fitted it to
/// this record, and `at` the same with its size replaced, so that the injected record holds
/// the effect at about the trial size whatever the record held of it already (adding the
/// trial size on top of a hidden delay of 2× it, the sum was recovered where the hidden
/// delay alone was not: PI force rig case 7409). Without such a fit, `base` is the model
/// and `at` the structure from its start values.
struct Trial<'t> {
    base: &'t Hyp,
    at: &'t dyn Fn(f64) -> Hyp,
}

/// The values of `inj`'s parameters in the search's round-0 fit `c` of its effect, when
/// that fit is of the same structure and has them all. Even a fit on a bound is taken: what
/// it holds of the effect is what the trial replaces (rejecting fits within 0.1 % of a bound
/// dropped a delay of 0.056 ms on the range [0, 60 ms], own plant seed 5133, and the trial
/// then added to the hidden delay instead of replacing it: 2.9× its limit unnamed).
fn fitted_values(inj: &Injection, c: Option<&Candidate>) -> Option<Vec<f64>> {
    let c = c.filter(|c| c.variant == inj.variant)?;
    inj.params
        .iter()
        .map(|p| c.params.get(&p.name).copied())
        .collect()
}

/// First step up from a linearised limit that its injection did not confirm, on the log
/// scale of the catalogue range (-): an eighth, a factor 3–4 on the usual ranges of 10⁴–10⁵.
/// (Going straight to the strongest end and then half way stated a delay limit of 2.0 ms on
/// the clean test-bench record where a delay of 0.68 ms is named.)
const STEP_UP: f64 = 0.125;

/// The linearised limit `lim` of `inj` checked by injection and recovery ([`recovered`]) at
/// its own size; not recovered there, one [`STEP_UP`] higher; not there either, half way to
/// the strongest end of the range on the log scale, then at that end (not recovered there:
/// not detectable with this record). Four fits at most per effect. Half way comes before the
/// end because the search's fit can miss an effect at the end of its range that it finds
/// half way (a mount of 17 kN/m, the catalogue's softest, on the clean generator record 7020:
/// "not detectable" where stiffer mounts are named). A record the injected model cannot
/// replay keeps the linearised limit.
fn confirm(
    env: &SearchEnv<'_, '_>,
    model: &Hyp,
    trial: &Trial<'_>,
    mut lim: DetectionLimit,
    inj: &Injection,
    evals_per_param: usize,
) -> DetectionLimit {
    let recovered_at = |s: f64| recovered(env, model, trial, inj, inj.at(s), evals_per_param);
    let s0 = lim.looseness;
    let s1 = (s0 + STEP_UP).min(1.0);
    let s = match recovered_at(s0) {
        None => return lim,
        Some(true) => Some((s0, "injected")),
        Some(false) if s0 >= 1.0 => None,
        Some(false) => match recovered_at(s1) {
            None => return lim,
            Some(true) => Some((s1, "raised by injection")),
            Some(false) if s1 >= 1.0 => None,
            Some(false) => {
                let mid = 0.5 * (s1 + 1.0);
                match recovered_at(mid) {
                    None => return lim,
                    Some(true) => Some((mid, "raised by injection")),
                    Some(false) => match recovered_at(1.0) {
                        None => return lim,
                        Some(true) => Some((1.0, "raised by injection")),
                        Some(false) => None,
                    },
                }
            }
        },
    };
    match s {
        Some((s, how)) => {
            lim.limit = Some(inj.at(s));
            lim.looseness = s;
            lim.method = how.to_string();
        }
        None => {
            lim.limit = None;
            lim.looseness = 1.0;
            lim.note = "not detectable with this record".to_string();
            lim.method = "injected".to_string();
        }
    }
    lim
}

/// Divisor of the search's evaluation budget per parameter for a check's refit and joint fit
/// (-): both start where the model stands, and the refit and joint fits took 84 % of the
/// check's replays on the clean test bench. Halved, the diagnosis with limits went from 2.45×
/// to 2.1× the one without (`diagnose_speed 101 none 1`, BENCHMARKS.md).
const CHECK_BUDGET_SHARE: usize = 2;

/// Whether the search would name `inj`'s effect on this record with the effect at size `v`:
/// the record plus the change of [`Trial`] (the record's own noise and misfit kept), `model`'s nominal parameters refit to it as the refit phase
/// does, the effect's structure fitted on top of that from the search's start values,
/// judged by round 0's test ([`judge`]), the edge rule and, for a joint fit, the effect's
/// share of the gain ([`MIN_EFFECT_SHARE`]). `None` when a replay fails.
fn recovered(
    env: &SearchEnv<'_, '_>,
    model: &Hyp,
    trial: &Trial<'_>,
    inj: &Injection,
    v: f64,
    evals_per_param: usize,
) -> Option<bool> {
    let (fit_rec, val_rec) = injected_records(env.ctx, trial.base, &(trial.at)(v))?;
    let ctx = Ctx {
        fit_rec: &fit_rec,
        val_rec: val_rec.as_ref().unwrap_or(&fit_rec),
        ..env.ctx.clone()
    };
    // The search's reference: the model's nominal parameters (not an effect's or the law's:
    // those the refit phase refits) refit to the injected record, what a refit absorbs of the
    // effect the record does not show. From where they stand, so with half a candidate's
    // budget ([`CHECK_BUDGET_SHARE`]), not the refit phase's 4× from the nominal values (on
    // the MTS README record, refitting every parameter of the model that way took the phase
    // to 4× the diagnosis without it).
    let budget = evals_per_param / CHECK_BUDGET_SHARE;
    let frozen = ctx.frozen(model);
    let (current, cur_train) = frozen.fit(nominal_part(model), usize::MAX, budget);
    let cenv = SearchEnv {
        nom: env.nom,
        ctx: &frozen,
        rf: env.rf,
    };
    let s = Search {
        found: SearchPhase {
            current: current.clone(),
            cur_train,
            ..SearchPhase::at_refit(env.rf)
        },
        cur_err: frozen.val_errors(&current).0,
    };
    if cenv.near_floor(&s.cur_err, 0) {
        return Some(false);
    }
    let candidate = |h: &Hyp, ctx: &Ctx<'_>, ctrain: f64| {
        let (err, _) = ctx.val_errors(h);
        let n = current.params.len() + inj.params.len();
        let jd = cenv.judge(&s, 0, false, (inj.effect, &err, ctrain, n));
        let edge = cenv.edge_within_floor(&s.cur_err, h, inj.effect, &err);
        (jd, edge.is_none(), err)
    };
    // The structure's own parameters alone on top of that refit first (a few parameters, so
    // cheap): passed, the search's fit (which can do no worse) passes too. A load-side mount
    // is fitted with its mass split as injected: the catalogue adds the load mass to the
    // piston's and the moving mass is not refit, so its own structure cannot follow a mass
    // taken from the piston.
    let on_top = frozen.frozen(&current);
    let alone = Hyp {
        effects: vec![inj.effect],
        variants: vec![inj.variant],
        values: inj.params.iter().map(|p| p.init).collect(),
        params: inj.params.clone(),
    };
    let (alone, ctrain) = on_top.fit(alone, 0, evals_per_param);
    let (jd, off_edge, _) = candidate(&alone, &on_top, ctrain);
    if jd.significant && off_edge {
        return Some(true);
    }
    // Else the search's own fit: the structure and the refit parameters together, which can
    // take back what the refit absorbed, and the effect's share of the gain.
    let first_new = current.params.len();
    let mut h = current.clone();
    h.effects.push(inj.effect);
    h.variants.push(inj.variant);
    h.values.extend(inj.params.iter().map(|p| p.init));
    h.params.extend(inj.params.iter().cloned());
    let (h, ctrain) = frozen.fit(h, first_new, budget);
    let (jd, off_edge, err) = candidate(&h, &frozen, ctrain);
    if !(jd.significant && off_edge) {
        return Some(false);
    }
    let wj = |x: &Errors| weighted_j(x, env.nom, env.floor_ch());
    let on_weighted: Option<&dyn Fn(&Errors) -> f64> =
        (!jd.on_mean && jd.on_weighted).then_some(&wj);
    let sh = effect_share(&frozen, &h, first_new, inj.effect, &s.cur_err, &err, on_weighted);
    Some(!(sh.share < MIN_EFFECT_SHARE && sh.err.overall.is_finite()))
}

/// The nominal parameters of `h` (those not of an effect) at their values, as a model of
/// its own.
fn nominal_part(h: &Hyp) -> Hyp {
    let (params, values) = h
        .params
        .iter()
        .zip(&h.values)
        .filter(|(p, _)| crate::limits::is_nominal(p))
        .map(|(p, v)| (p.clone(), *v))
        .unzip();
    Hyp {
        effects: vec![],
        variants: vec![],
        params,
        values,
    }
}

/// The fit record (and the held-out record, when it is a separate file) plus the change
/// from `base`'s replay to `with`'s on every channel; `None` when either replay fails.
fn injected_records(ctx: &Ctx<'_>, base: &Hyp, with: &Hyp) -> Option<(Record, Option<Record>)> {
    let fit = |h: &Hyp| ctx.fit_replay(&h.build(&ctx.fit_base)).ok();
    let fit_rec = plus_change(ctx.fit_rec, &fit(base)?.y, &fit(with)?.y)?;
    if std::ptr::eq(ctx.val_rec, ctx.fit_rec) {
        return Some((fit_rec, None));
    }
    let (a, b) = (ctx.val_errors(base).1, ctx.val_errors(with).1);
    if a.failed || b.failed {
        return None;
    }
    Some((fit_rec, Some(plus_change(ctx.val_rec, &a.y, &b.y)?)))
}

/// `rec` with `to − from` added to each channel; `None` when the change is not finite.
fn plus_change(rec: &Record, from: &[Vec<f64>], to: &[Vec<f64>]) -> Option<Record> {
    let mut out = rec.clone();
    for (c, (a, b)) in out.channels.iter_mut().zip(from.iter().zip(to)) {
        for (x, (p, q)) in c.values.iter_mut().zip(a.iter().zip(b)) {
            let d = q - p;
            if !d.is_finite() {
                return None;
            }
            *x += d;
        }
    }
    Some(out)
}
