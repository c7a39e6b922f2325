//! One round of the search: judging its fits, moving the current model onto a better refit,
//! accepting the winner.

use super::*;

/// Judges a round's fits: each effect's best variant by held-out score against the current
/// model, its candidate entry (round 0, or the first round it could be fitted) with the
/// evidence in words; returns those that passed, best score first, and every effect's best
/// variant for the second look at a weak winner, best score first.
pub(super) fn judge_round(
    env: &SearchEnv<'_, '_>,
    s: &mut Search,
    fits: BTreeMap<EffectId, Vec<VariantFit>>,
    round: usize,
    near_floor: bool,
    first_new: usize,
) -> (Vec<Passing>, Vec<Tried>) {
    let mut passing: Vec<Passing> = Vec::new();
    let mut tried: Vec<Tried> = Vec::new();
    for (e, vfits) in fits {
        let prior = env.prior_of(e);
        // The effect's best variant by held-out score, and the others for the evidence.
        let mut scored: Vec<(&'static str, f64, Hyp, f64, Errors)> = vfits
            .into_iter()
            .filter_map(|(v, r)| {
                r.map(|(h, c, err)| {
                    let sc = score(err.overall.powi(2), h.params.len());
                    (v, sc, h, c, err)
                })
            })
            .collect();
        scored.sort_by(|a, b| a.1.total_cmp(&b.1));
        let variants_note = if scored.len() > 1 {
            format!(
                " Variants (held-out NRMSE): {}.",
                scored
                    .iter()
                    .map(|s| format!("{} {:.4}", s.0, s.4.overall))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        } else {
            String::new()
        };
        let Some((variant, sc, h, ctrain, err)) = scored.into_iter().next() else {
            if round == 0 {
                s.found.candidates.insert(e, untestable(e, &prior));
            }
            continue;
        };
        let mut jd = env.judge(s, round, near_floor, (e, &err, ctrain, h.params.len()));
        let edge_note = jd
            .significant
            .then(|| env.edge_within_floor(&s.cur_err, &h, e, &err))
            .flatten();
        // The verdict of the acceptance test itself, then why it is overruled.
        let verdict = verdict(env, s, &jd, &err) + edge_note.as_deref().unwrap_or("");
        if edge_note.is_some() {
            jd.significant = false;
        }
        if round == 0 || !s.found.candidates.contains_key(&e) {
            let n_new = h.params.len() - first_new;
            s.found.candidates.insert(
                e,
                Candidate {
                    effect: e.as_str().into(),
                    variant: variant.into(),
                    params: new_params(&h, first_new),
                    nrmse_train: ctrain.sqrt(),
                    nrmse_validation: err.overall,
                    score: sc,
                    accepted: false,
                    evidence: format!(
                        "{prior}; {verdict} with {n_new} parameter(s){}{variants_note}",
                        if variant == "-" {
                            String::new()
                        } else {
                            format!(", variant `{variant}`")
                        }
                    ),
                },
            );
        }
        tried.push((
            (e, sc, h.clone(), ctrain, err.clone()),
            jd.excess_ratio,
            jd.significant,
        ));
        if jd.significant {
            passing.push((e, sc, h, ctrain, err));
        }
    }
    passing.sort_by(|a, b| a.1.total_cmp(&b.1));
    tried.sort_by(|a, b| a.0 .1.total_cmp(&b.0 .1));
    (passing, tried)
}

/// The candidate entry of an effect none of whose variants could be fitted on this record.
pub(super) fn untestable(e: EffectId, prior: &str) -> Candidate {
    Candidate {
        effect: e.as_str().into(),
        variant: "-".into(),
        params: BTreeMap::new(),
        nrmse_train: f64::NAN,
        nrmse_validation: f64::NAN,
        score: f64::NAN,
        accepted: false,
        evidence: format!("not testable on this record: {prior}"),
    }
}

/// The fitted values of a candidate's own parameters (those from `first_new` on), by name.
pub(super) fn new_params(h: &Hyp, first_new: usize) -> BTreeMap<String, f64> {
    h.params[first_new..]
        .iter()
        .zip(&h.values[first_new..])
        .map(|(p, v)| (p.name.clone(), *v))
        .collect()
}

/// The judgement `jd` of a candidate with held-out errors `err` in words.
pub(super) fn verdict(env: &SearchEnv<'_, '_>, s: &Search, jd: &Judgement, err: &Errors) -> String {
    let cur_err = &s.cur_err;
    let how = match (jd.significant, jd.on_mean, jd.on_channel) {
        (false, _, _) => " — not significant".to_string(),
        (true, false, _) if jd.on_weighted => format!(
            " (significant on the floor-weighted J: {:.2} → {:.2})",
            weighted_j(cur_err, env.nom, env.floor_ch()),
            weighted_j(err, env.nom, env.floor_ch())
        ),
        (true, false, Some(c)) => format!(
            " (significant on `{c}`: {:.4} → {:.4})",
            cur_err.channels.get(c).copied().unwrap_or(f64::NAN),
            err.channels.get(c).copied().unwrap_or(f64::NAN)
        ),
        _ => String::new(),
    };
    format!(
        "fit: held-out NRMSE {:.4} → {:.4} ({:+.1} %), {:.0} % of the error above the noise floor explained{how}",
        cur_err.overall,
        err.overall,
        100.0 * (err.overall / cur_err.overall - 1.0),
        100.0 * (1.0 - jd.excess_ratio.min(1.0)),
    )
}

/// The effect must carry its gain (MIN_EFFECT_SHARE). When the best candidate's gain is its
/// refit's, not its effect's, that refit (without the effect) becomes the current model and
/// the round is fitted again from it: every candidate is then judged on what it adds to the
/// better model. A round refitted once (`refitted_round`) judges its candidates in `passing`
/// again against any further such model instead of fitting them a third time. Returns
/// whether the current model moved.
pub(super) fn rebase_round(
    env: &SearchEnv<'_, '_>,
    s: &mut Search,
    passing: &mut Vec<Passing>,
    round: usize,
    first_new: usize,
    refitted_round: bool,
) -> bool {
    let (nom, floor_ch) = (env.nom, env.floor_ch());
    let ctx = env.ctx;
    let mut rebased_now = false;
    while let Some((e, _, h, ctrain, err)) = passing.first() {
        // A candidate that passed on the floor-weighted J alone carries its gain there.
        let jd = env.judge(s, round, false, (*e, err, *ctrain, h.params.len()));
        let wj = |x: &Errors| weighted_j(x, nom, floor_ch);
        let on_weighted: Option<&dyn Fn(&Errors) -> f64> =
            (!jd.on_mean && jd.on_weighted).then_some(&wj);
        let sh = effect_share(ctx, h, first_new, *e, &s.cur_err, err, on_weighted);
        // (A share that is not a number keeps the effect: never move onto a model whose
        // replay could not be scored.)
        if !(sh.share < MIN_EFFECT_SHARE && sh.err.overall.is_finite()) {
            break;
        }
        let e = *e;
        let note = format!(
            "the {} candidate's fit without its effect lowered the held-out NRMSE of the current model {:.4} → {:.4} (with the effect {:.4}: {:.0} % of the gain on {} is the effect's, at least {:.0} % must be), so round {} went on from that model",
            e.as_str(),
            s.cur_err.overall,
            sh.err.overall,
            err.overall,
            100.0 * sh.share.max(0.0),
            sh.on,
            100.0 * MIN_EFFECT_SHARE,
            round + 1
        );
        if let Some(c) = s.found.candidates.get_mut(&e) {
            c.evidence = format!("{} Not accepted: {note}.", c.evidence);
        }
        s.found.rebased.push(note);
        rebased_now = true;
        s.found.cur_train = ctx.train_cost(&sh.model);
        s.found.current = sh.model;
        s.cur_err = sh.err;
        if !refitted_round {
            break;
        }
        let near_floor = env.near_floor(&s.cur_err, round);
        passing.retain(|(e, _, h, ctrain, err)| {
            env.judge(s, round, near_floor, (*e, err, *ctrain, h.params.len()))
                .significant
        });
    }
    rebased_now
}

/// Accepts the round's winner `best` (the best of `passing`), after the second look when it
/// is weak evidence, reporting the near-ties among `passing` as ambiguities; in later rounds
/// its candidate entry gets the numbers of the round it was accepted in.
pub(super) fn accept(
    env: &SearchEnv<'_, '_>,
    s: &mut Search,
    mut best: Passing,
    passing: &[Passing],
    tried: &[Tried],
    round: usize,
    first_new: usize,
) {
    let jn = env.jn();
    let dt = env.nom.val_rec.dt;
    let edge_of =
        |p: &Passing| crate::edge::edge_reasons(&p.2, p.0, dt, crate::edge::NAMED_BOUND_SHARE);
    let mut looked: Option<EffectId> = None;
    if let Some((note, alt)) = inside_alternative(&best, passing, &edge_of) {
        s.found.ambiguities.push(note);
        looked = Some(best.0);
        best = alt;
    }
    // A weak winner is compared with the runner-up on the evidence that tells them apart (a
    // runner-up at the edge of its range is not named for it).
    if let Some((note, runner, prefer)) = weak_winner(env, &best, tried, first_new) {
        looked = Some(runner.0);
        let runner_edge = edge_of(&runner);
        if prefer && !runner_edge.is_empty() {
            s.found.ambiguities.push(format!(
                "{note} (`{}` is not named after all: its fit is at the edge of its range, {})",
                runner.0.as_str(),
                runner_edge.join("; ")
            ));
        } else {
            s.found.ambiguities.push(note);
        }
        if prefer && runner_edge.is_empty() {
            looked = Some(best.0);
            best = runner;
        }
        s.found.weak.push(best.0);
    }
    let j_best = best.4.overall.powi(2);
    for other in passing
        .iter()
        .filter(|o| o.0 != best.0 && Some(o.0) != looked)
    {
        let j_o = other.4.overall.powi(2);
        if (j_o - jn).max(0.0) <= 1.15 * (j_best - jn).max(1e-300) + 0.02 * j_best {
            s.found.ambiguities.push(format!(
                "{} and {} fit the held-out data about equally well (NRMSE {:.4} vs {:.4}); {} is preferred by score. To separate them: {}",
                best.0.as_str(), other.0.as_str(), best.4.overall, other.4.overall, best.0.as_str(), crate::weigh::separating_experiment(best.0, other.0)
            ));
        }
    }
    let (e, _, h, ctrain, err) = best;
    if round > 0 {
        // Report the numbers of the round in which the effect was accepted.
        let j_cur = s.cur_err.overall.powi(2);
        let on_top = s
            .found
            .accepted
            .iter()
            .map(|a| a.as_str())
            .collect::<Vec<_>>()
            .join(" + ");
        if let Some(c) = s.found.candidates.get_mut(&e) {
            let j = err.overall.powi(2);
            let excess_ratio = (j - jn).max(0.0) / (j_cur - jn).max(1e-300);
            c.params = new_params(&h, first_new);
            c.variant = h.variants.last().copied().unwrap_or("-").to_string();
            c.nrmse_train = ctrain.sqrt();
            c.nrmse_validation = err.overall;
            c.score = score(j, h.params.len());
            c.evidence = format!(
                "{}; accepted in round {} on top of {on_top}: held-out NRMSE {:.4} → {:.4}, {:.0} % of the remaining error above the noise floor explained",
                env.prior_of(e),
                round + 1,
                s.cur_err.overall,
                err.overall,
                100.0 * (1.0 - excess_ratio.min(1.0))
            );
        }
    }
    if let Some(c) = s.found.candidates.get_mut(&e) {
        c.accepted = true;
    }
    s.found.accepted.push(e);
    s.found.current = h;
    s.cur_err = err;
    s.found.cur_train = ctrain;
}

/// A winner at the edge of its range has no precedence over a candidate that passed inside
/// its own: the best of those in `passing` is named instead of `best` (DIAGNOSIS.md step 7,
/// "An edge fit is not a cause"), with the ambiguity sentence; `None` when `best` is inside
/// its range (`edge_of` gives no reason) or no other candidate is.
fn inside_alternative(
    best: &Passing,
    passing: &[Passing],
    edge_of: &dyn Fn(&Passing) -> Vec<String>,
) -> Option<(String, Passing)> {
    let best_edge = edge_of(best);
    if best_edge.is_empty() {
        return None;
    }
    let alt = passing
        .iter()
        .find(|p| p.0 != best.0 && edge_of(p).is_empty())?;
    let note = format!(
        "`{}` fits best by held-out score (NRMSE {:.4}) but at the edge of its range ({}); `{}` (NRMSE {:.4}) passed the acceptance test inside its own range, so it is named. To separate them: {}",
        best.0.as_str(),
        best.4.overall,
        best_edge.join("; "),
        alt.0.as_str(),
        alt.4.overall,
        crate::weigh::separating_experiment(best.0, alt.0)
    );
    Some((note, alt.clone()))
}

/// A fitted candidate of one round: (effect, score, model, training cost, held-out errors),
/// the share of the error above the floor it leaves, and whether it passed [`judge`].
pub(super) type Tried = (Passing, f64, bool);

/// A candidate that passed [`judge`]: (effect, score, model, training cost, held-out errors).
pub(super) type Passing = (EffectId, f64, Hyp, f64, Errors);

/// The second look at round winner `best` ([`crate::weigh::second_look`]) against the
/// best-scoring other effect of the round in `tried`: the ambiguity sentence, the runner-up
/// and whether it is named instead; `None` when the winner is not weak evidence.
pub(super) fn weak_winner(
    env: &SearchEnv<'_, '_>,
    best: &Passing,
    tried: &[Tried],
    first_new: usize,
) -> Option<(String, Passing, bool)> {
    use crate::weigh::{second_look, Fitted};
    let (nom, floor_ch, ctx) = (env.nom, env.floor_ch(), env.ctx);
    let w = tried.iter().find(|t| t.0 .0 == best.0)?;
    let r = tried
        .iter()
        .find(|t| t.0 .0 != best.0 && t.0 .4.overall.is_finite())?;
    fn fitted(t: &Tried) -> Fitted<'_> {
        Fitted {
            e: t.0 .0,
            h: &t.0 .2,
            err: &t.0 .4,
            excess: t.1,
            significant: t.2,
        }
    }
    let floors: Vec<(String, f64)> = nom
        .val_rec
        .channels
        .iter()
        .zip(floor_ch)
        .map(|(c, f)| (c.kind.column().to_string(), *f))
        .collect();
    let look = second_look(ctx, &fitted(w), &fitted(r), first_new, &floors)?;
    Some((look.note, r.0.clone(), look.prefer_runner_up))
}
